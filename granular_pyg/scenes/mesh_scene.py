"""A Scene from STL files: users describe their own equipment (``conf/scene/mesh.yaml``).

Each wall is an STL file (ASCII or binary) with its own units, scale, offset, motion and removal
time; particles (one radius or a discrete distribution) are rained into a box or a vertical
cylinder that is checked to lie inside the walls before LIGGGHTS starts
(:func:`~granular_pyg.scenes.containment.check_insertion_region`).

Lengths: STL coordinates are in the wall's ``units`` (``m``, ``cm`` or ``mm``); every other
length of the call (offsets, insertion region, motion origin, velocity and amplitude, outflow,
outlet and domain) is in metres. ``scale`` then multiplies every length of the equipment about
the world origin (walls, offsets, region, motions, outflow, outlet, domain), but not the particle
radii or the times, so that ``generate``'s ``ranges`` can draw the equipment's size. Everything
``ranges`` may draw is a top-level scalar: ``scale``, ``num_particles``, ``particle_radius``,
``density``, ``youngs_modulus``, ``poisson_ratio``, ``restitution``, ``friction``,
``rolling_friction``, ``omega`` (the angular velocity of every rotating wall), the times.

STL paths: an absolute path is used as it is; a relative one is looked up in the package's
``granular_pyg/scenes/meshes/`` folder first (the shipped examples, so they work from an
installed wheel) and then in the working directory.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from granular_pyg.errors import InputError
from granular_pyg.scenes.containment import check_insertion_region
from granular_pyg.scenes.scene import Materials, ParticleSpec, Scene, Wall, WallMotion

__all__ = ["MESH_DIR", "UNITS", "load_stl", "make_mesh_scene", "resolve_mesh_path"]

#: The package's folder of shipped STL files; relative paths are looked up here first.
MESH_DIR = Path(__file__).resolve().parent / "meshes"
#: Metres per STL unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Keys of one wall's entry in ``walls``.
WALL_KEYS = ("file", "units", "scale", "offset", "motion", "removal_time")
#: Motion keys holding lengths (scaled with the equipment).
_LENGTH_KEYS = ("origin", "velocity", "amplitude")
_MOTION_KEYS = (
    "kind",
    "axis",
    "origin",
    "omega",
    "start_time",
    "velocity",
    "amplitude",
    "period",
    "stop_time",
    "reverse_times",
)


def resolve_mesh_path(path: str | os.PathLike) -> Path:
    """The STL file ``path`` names: absolute as given; relative in :data:`MESH_DIR` if there,
    else in the working directory.

    Raises:
        FileNotFoundError: naming every place looked in.
    """
    path = Path(path).expanduser()
    candidates = [path] if path.is_absolute() else [MESH_DIR / path, Path.cwd() / path]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"STL file {str(path)!r} not found (looked in: {', '.join(map(str, candidates))}); "
        "give an absolute path, or one relative to the working directory"
    )


def load_stl(path: str | os.PathLike, units: str = "m") -> tuple[np.ndarray, np.ndarray]:
    """Read an STL file (ASCII or binary) into metres.

    Exactly coincident vertices are merged (STL stores three per triangle); the triangles are
    kept as they are.

    Args:
        path: the file (see :func:`resolve_mesh_path`).
        units: the file's length unit, a key of :data:`UNITS`.

    Returns:
        ``(vertices [V, 3] float64 (m), faces [F, 3] int64)``.

    Raises:
        FileNotFoundError: no such file.
        InputError: unknown units, or a file that is not a readable STL mesh.
    """
    if units not in UNITS:
        raise InputError(f"units: expected one of {sorted(UNITS)} for {path}, got {units!r}")
    vertices, faces = read_stl(resolve_mesh_path(path))
    return vertices * UNITS[units], faces


def read_stl(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The triangles of the STL file ``path`` (ASCII or binary) in its own units, with exactly
    coincident vertices merged and the triangles kept in file order.

    Returns:
        ``(vertices [V, 3] float64, faces [F, 3] int64)``.

    Raises:
        InputError: an unreadable file or one without triangles.
    """
    try:
        mesh = trimesh.load(path, file_type="stl", force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for bad files
        raise InputError(
            f"{path}: cannot read this STL file ({err}); export it again as ASCII or binary STL"
        ) from err
    faces = np.asarray(getattr(mesh, "faces", np.empty((0, 3))), np.int64)
    if faces.ndim != 2 or len(faces) == 0:
        _check_binary_count(path)
        raise InputError(f"{path}: the STL file holds no triangles; export the mesh again")
    vertices, inverse = np.unique(
        np.asarray(mesh.vertices, np.float64), axis=0, return_inverse=True
    )
    faces = inverse.reshape(-1)[faces]
    _check_some_area(path, vertices, faces)
    return vertices, faces


def _check_binary_count(path: Path) -> None:
    """Refuse a binary STL whose header counts more triangles than the file holds (a truncated
    file, or a header another tool got wrong), naming both counts."""
    size = path.stat().st_size
    with open(path, "rb") as handle:
        head = handle.read(84)
    if size < 84 or (head.lstrip().lower().startswith(b"solid") and b"\0" not in head[:80]):
        return
    count = int.from_bytes(head[80:84], "little")
    held = (size - 84) // 50
    if count > held:
        raise InputError(
            f"{path}: its binary STL header counts {count} triangles but the file holds "
            f"{held} ({size} bytes); the file is truncated or its header is wrong; export the "
            "mesh again"
        )


def _check_some_area(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Refuse a mesh whose every triangle has zero area (repeated or collinear vertices): a
    wall that would stop nothing."""
    tri = vertices[faces]
    extent = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not (area > 1e-12 * extent**2).any():
        raise InputError(
            f"{path}: all {len(faces)} triangles of the STL file have zero area (repeated or "
            "collinear vertices), so the wall would stop nothing; export the mesh again"
        )


def _vector(name: str, value: Any, size: int) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64) if value is not None else None
    if array is None or array.shape != (size,) or not np.isfinite(array).all():
        raise InputError(f"{name}: expected {size} finite numbers, got {value!r}")
    return array


def _motion(wall: str, spec: Mapping[str, Any] | None, scale: float, omega: float | None):
    """The wall's :class:`WallMotion` from its config entry, lengths scaled."""
    spec = dict(spec or {})
    unknown = set(spec) - set(_MOTION_KEYS)
    if unknown:
        raise InputError(
            f"wall {wall}: unknown motion keys {sorted(unknown)}; use {list(_MOTION_KEYS)}"
        )
    for key in ("axis", *_LENGTH_KEYS):
        if key in spec:
            spec[key] = tuple(_vector(f"wall {wall}: motion.{key}", spec[key], 3))
    for key in _LENGTH_KEYS:
        if key in spec:
            spec[key] = tuple(scale * np.asarray(spec[key]))
    if omega is not None and spec.get("kind") == "rotation":
        spec["omega"] = float(omega)
    try:
        return WallMotion(**spec)
    except InputError as err:
        raise InputError(f"wall {wall}: {err}") from err


def _wall(name: str, spec: Mapping[str, Any], units: str, scale: float, omega) -> Wall:
    """The wall ``name`` from its config entry (see :func:`make_mesh_scene`), in metres."""
    if not isinstance(spec, Mapping) or "file" not in spec:
        raise InputError(f"wall {name}: expected a mapping with at least 'file', got {spec!r}")
    unknown = set(spec) - set(WALL_KEYS)
    if unknown:
        raise InputError(f"wall {name}: unknown keys {sorted(unknown)}; use {list(WALL_KEYS)}")
    vertices, faces = load_stl(spec["file"], spec.get("units") or units)
    own_scale = float(spec.get("scale", 1.0))
    if not (math.isfinite(own_scale) and own_scale > 0):
        raise InputError(f"wall {name}: scale must be a positive number, got {own_scale}")
    offset = _vector(f"wall {name}: offset", spec.get("offset", (0.0, 0.0, 0.0)), 3)
    removal = spec.get("removal_time")
    return Wall(
        name=name,
        vertices=(vertices * own_scale + offset) * scale,
        faces=faces,
        motion=_motion(name, spec.get("motion"), scale, omega),
        removal_time=None if removal is None else float(removal),
    )


def _particles(
    count: int,
    radius: float | None,
    radii: Sequence[float] | None,
    weights: Sequence[float] | None,
    insertion: Mapping[str, Any],
    scale: float,
) -> ParticleSpec:
    """The :class:`ParticleSpec` of the size arguments and the insertion region (scaled)."""
    if radii is not None and radius is not None:
        raise InputError(
            "particle_radius and particle_radii: give one (a single radius, or a distribution "
            "with radius_weights), set the other to null"
        )
    if radii is not None:
        radii = tuple(float(r) for r in radii)
        if not radii:
            raise InputError("particle_radii: expected at least one radius (m), got []")
        sizes = {"radii": radii, "radius_weights": None if weights is None else tuple(weights)}
        radius = max(radii)
    else:
        if weights is not None:
            raise InputError("radius_weights: given without particle_radii")
        radius = 0.0015 if radius is None else float(radius)
        sizes = {}
    if not (math.isfinite(radius) and radius > 0):
        raise InputError(f"particle_radius: expected a positive radius (m), got {radius}")
    if int(count) != count or count < 1:
        raise InputError(f"num_particles: expected a positive integer, got {count!r}")
    if not isinstance(insertion, Mapping):
        raise InputError(f"insertion: expected a mapping with a 'shape', got {insertion!r}")
    shape = insertion.get("shape", "box")
    keys = {"box": {"shape", "lo", "hi"}, "cylinder": {"shape", "centre", "radius", "z"}}
    if shape not in keys:
        raise InputError(f"insertion.shape: expected 'box' or 'cylinder', got {shape!r}")
    if set(insertion) - keys[shape] or not (keys[shape] - {"shape"}) <= set(insertion):
        raise InputError(
            f"insertion: a {shape} takes exactly the keys {sorted(keys[shape])}, got "
            f"{sorted(insertion)}"
        )
    if shape == "box":
        lo = scale * _vector("insertion.lo", insertion["lo"], 3)
        hi = scale * _vector("insertion.hi", insertion["hi"], 3)
        if np.any(lo >= hi):
            raise InputError(f"insertion: lo {lo.tolist()} must lie below hi {hi.tolist()}")
        return ParticleSpec(int(count), radius, tuple(lo.tolist()), tuple(hi.tolist()), **sizes)
    centre = scale * _vector("insertion.centre", insertion["centre"], 2)
    z = scale * _vector("insertion.z", insertion["z"], 2)
    cyl = scale * float(insertion["radius"])
    if not (cyl > 0 and z[0] < z[1]):
        raise InputError(
            f"insertion: a cylinder needs radius > 0 and z = [low, high], got radius {cyl}, "
            f"z {z.tolist()}"
        )
    return ParticleSpec.cylinder_region(
        int(count), radius, tuple(centre.tolist()), cyl, tuple(z.tolist()), **sizes
    )


def make_mesh_scene(
    walls: Mapping[str, Mapping[str, Any]],
    insertion: Mapping[str, Any],
    num_particles: int = 1000,
    particle_radius: float | None = None,
    particle_radii: Sequence[float] | None = None,
    radius_weights: Sequence[float] | None = None,
    density: float = 2500.0,
    youngs_modulus: float = 5.0e6,
    poisson_ratio: float = 0.3,
    restitution: float = 0.6,
    friction: float = 0.5,
    rolling_friction: float = 0.0,
    units: str = "m",
    scale: float = 1.0,
    omega: float | None = None,
    outflow_z: float | None = None,
    outlet_z: float | None = None,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
    domain_lo: Sequence[float] | None = None,
    domain_hi: Sequence[float] | None = None,
    domain_padding: float | None = None,
    dem_dt: float = 2.0e-5,
    settle_time: float = 0.5,
    duration: float = 1.0,
    frame_dt: float = 2.5e-3,
    kind: str = "other",
    name: str = "mesh",
) -> Scene:
    """Build a Scene from STL walls (see the module docstring for lengths and paths).

    Args:
        walls: wall name (an identifier) -> ``{file, units?, scale?, offset?, motion?,
            removal_time?}``: the STL file; its units (default ``units``); its own scale
            factor about the file's origin and ``offset`` ``[3]`` (m) added after it; its
            motion as :class:`~granular_pyg.scenes.WallMotion` fields (``kind``: static,
            rotation, translation or oscillation; default static); the recorded time (s) at
            which it disappears (a lid), default never.
        insertion: where particles are rained in, ``{shape: box, lo: [3], hi: [3]}`` or
            ``{shape: cylinder, centre: [x, y], radius: r, z: [low, high]}`` (m; the cylinder's
            axis is z). Checked to lie inside the walls, at least one particle radius from each.
        num_particles: particles inserted.
        particle_radius: one radius (m); 1.5 mm when neither it nor ``particle_radii`` is set.
        particle_radii: ``[K]`` radii (m) of a discrete size distribution instead.
        radius_weights: ``[K]`` number fractions of ``particle_radii`` (equal by default).
        density, youngs_modulus, poisson_ratio, restitution, friction, rolling_friction: the
            materials (SI; see :class:`~granular_pyg.scenes.Materials`).
        units: default STL unit, ``m``, ``cm`` or ``mm``.
        scale: factor on every length of the equipment (not on particle radii or times).
        omega: when given, the angular velocity (rad/s) of every rotating wall, replacing their
            own (so that ``ranges`` can draw it).
        outflow_z: height (m) below which particles leave (the box's floor), or None for a closed
            scene; must lie below every wall.
        outlet_z: height (m) of the outlet, stored in ``params`` for the discharge metrics.
        gravity: ``[3]`` (m/s^2).
        domain_lo, domain_hi: the simulation box (m); by default the box around every wall at
            every pose, padded by ``domain_padding`` (default four particle radii), with its
            floor at ``outflow_z`` when given.
        dem_dt, settle_time, duration, frame_dt: see :class:`~granular_pyg.scenes.Scene` (s).
        kind: ``"hopper"``, ``"drum"`` or ``"other"`` (see :class:`~granular_pyg.scenes.Scene`).
        name: the scene's name.

    Returns:
        The Scene, its ``params`` the arguments (wall files as given).

    Raises:
        FileNotFoundError: an STL file is missing.
        InputError: a malformed argument, or an insertion region not inside the walls (naming
            the region, the wall and the fix).
    """
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise InputError(f"scale: expected a positive factor, got {scale!r}")
    if not isinstance(walls, Mapping) or not walls:
        raise InputError("walls: expected a mapping of wall name -> {file: ..., ...}")
    built = [_wall(str(n), spec, units, float(scale), omega) for n, spec in walls.items()]
    if omega is not None and not any(w.motion.kind == "rotation" for w in built):
        raise InputError("omega: given, but no wall has a rotation motion to apply it to")
    particles = _particles(
        num_particles, particle_radius, particle_radii, radius_weights, insertion, float(scale)
    )
    if outflow_z is not None:
        outflow_z = float(outflow_z) * scale
    lows, highs = zip(*(w.swept_bounds(duration) for w in built), strict=True)
    wall_lo, wall_hi = np.min(lows, axis=0), np.max(highs, axis=0)
    if outflow_z is not None and wall_lo[2] < outflow_z:
        raise InputError(
            f"outflow_z ({outflow_z:.4g} m after scaling) must lie below every wall (lowest "
            f"at z = {wall_lo[2]:.4g} m): particles leave through the box's floor"
        )
    pad = 4 * particles.radius if domain_padding is None else float(domain_padding)
    lo = wall_lo - pad if domain_lo is None else scale * _vector("domain_lo", domain_lo, 3)
    hi = wall_hi + pad if domain_hi is None else scale * _vector("domain_hi", domain_hi, 3)
    if outflow_z is not None and domain_lo is None:
        lo[2] = outflow_z
    params = {
        "walls": {n: dict(spec) for n, spec in walls.items()},
        "insertion": dict(insertion),
        "num_particles": int(num_particles),
        "particle_radius": particles.radius,
        "particle_radii": None if particle_radii is None else list(particles.radii),
        "radius_weights": None
        if particles.radius_weights is None
        else list(particles.radius_weights),
        "units": units,
        "scale": float(scale),
        "omega": omega,
        "outlet_z": None if outlet_z is None else float(outlet_z) * scale,
    }
    materials = Materials(
        youngs_modulus=float(youngs_modulus),
        poisson_ratio=float(poisson_ratio),
        restitution=float(restitution),
        friction=float(friction),
        rolling_friction=float(rolling_friction),
        density=float(density),
    )
    scene = Scene(
        name=name,
        walls=built,
        particles=particles,
        materials=materials,
        gravity=tuple(_vector("gravity", gravity, 3).tolist()),
        domain_lo=tuple(float(v) for v in lo),
        domain_hi=tuple(float(v) for v in hi),
        outflow_z=outflow_z,
        dem_dt=float(dem_dt),
        settle_time=float(settle_time),
        duration=float(duration),
        frame_dt=float(frame_dt),
        params=params,
        kind=kind,
    )
    check_insertion_region(scene, fix="move or shrink `insertion` (lo/hi, or centre/radius/z)")
    return scene
