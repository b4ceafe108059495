"""Import your own LIGGGHTS runs: ``dump custom`` files + STL walls -> a Trajectory file.

Command line::

    python -m granular_pyg.dem.convert DUMPS --stl A.stl B.stl --dem-dt 2e-5 --out traj.h5

``DUMPS`` is a dump file or a folder of dump files (``--pattern`` selects names in a folder).
The dump needs the columns ``id x y z vx vy vz radius`` (e.g. ``dump d all custom 125 post/dump
id type x y z vx vy vz radius``). STL files (ASCII or binary, in metres, at their pose in the
run) become static walls named after the file stem. Wall motion, removal times and materials are
not in a dump: the imported Scene has static walls and default materials; edit the Scene
(``traj.scene``) if your run moved a wall.
"""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from granular_pyg.cli import reports_errors
from granular_pyg.dem.dump import frames_to_arrays, read_dump
from granular_pyg.errors import InputError
from granular_pyg.io.trajectory import Trajectory, write_trajectory
from granular_pyg.scenes.scene import ParticleSpec, Scene, Wall

__all__ = ["load_stl_wall", "main", "trajectory_from_dumps"]


def trajectory_from_dumps(
    dumps: str | os.PathLike,
    stl_files: Sequence[str | os.PathLike],
    dem_dt: float,
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81),
    outflow_z: float | None = None,
    on_truncated: str = "warn",
    pattern: str = "*",
) -> Trajectory:
    """Build a Trajectory (with an ``"imported"`` Scene) from LIGGGHTS dumps and STL walls.

    Args:
        dumps: a ``dump custom`` file or a folder of them (see
            :func:`granular_pyg.dem.dump.read_dump`).
        stl_files: STL meshes (ASCII or binary, metres) that become static walls named after
            their file stems, sanitised to identifiers (``hopper-left.stl`` -> ``hopper_left``).
        dem_dt: the run's DEM time step (s); times are ``(timestep - first) * dem_dt``.
        gravity: ``[3]`` gravitational acceleration of the run (m/s^2).
        outflow_z: height (m) below which particles left the run, or None for a closed scene;
            becomes the scene's ``domain_lo`` z.
        on_truncated: ``"warn"`` drops a truncated last frame with a warning, ``"raise"`` fails.
        pattern: glob for dump file names when ``dumps`` is a folder.

    Returns:
        The trajectory. Its Scene has ``ParticleSpec(count=N, radius=max radius, fill box =
        bounding box of the first frame)``, the first frame's box as domain, ``frame_dt`` the
        recorded spacing rounded to a multiple of ``dem_dt``, ``settle_time = 0``, ``duration``
        the last recorded time; metadata ``{"source": "imported", "dumps", "stl_files",
        "first_timestep"}``.

    Raises:
        FileNotFoundError: a dump path or STL file does not exist.
        InputError: malformed dumps, an unreadable or empty STL file, bad ``dem_dt`` or
            ``outflow_z``.
    """
    if not (isinstance(dem_dt, (int, float)) and np.isfinite(dem_dt) and dem_dt > 0):
        raise InputError(f"dem_dt: expected the run's positive DEM time step (s), got {dem_dt!r}")
    frames = read_dump(dumps, on_truncated=on_truncated, pattern=pattern)
    arrays = frames_to_arrays(frames, dem_dt)
    first_timestep = arrays.pop("first_timestep")

    walls: list[Wall] = []
    for stl in stl_files:
        name = _unique(_identifier(Path(stl).stem), {w.name for w in walls})
        walls.append(load_stl_wall(stl, name))

    first = frames[0]
    xyz = first.data[:, [first.columns.index(c) for c in ("x", "y", "z")]]
    if len(xyz):
        fill_lo, fill_hi = xyz.min(axis=0), xyz.max(axis=0)
    else:
        fill_lo, fill_hi = first.box[:, 0], first.box[:, 1]
    domain_lo, domain_hi = first.box[:, 0].copy(), first.box[:, 1].copy()
    if outflow_z is not None:
        if not (np.isfinite(outflow_z) and outflow_z < domain_hi[2]):
            raise InputError(
                f"outflow_z: {outflow_z} must be finite and below the box top "
                f"({domain_hi[2]} m) of {first.where}"
            )
        domain_lo[2] = float(outflow_z)

    steps = np.diff([f.timestep for f in frames])
    frame_steps = max(1, round(float(np.median(steps)))) if len(steps) else 1
    scene = Scene(
        name="imported",
        walls=walls,
        particles=ParticleSpec(
            count=len(arrays["ids"]),
            radius=float(np.max(arrays["radii"])) if len(arrays["radii"]) else 0.0,
            fill_lo=_floats(fill_lo),
            fill_hi=_floats(fill_hi),
        ),
        gravity=_floats(gravity),
        domain_lo=_floats(domain_lo),
        domain_hi=_floats(domain_hi),
        outflow_z=None if outflow_z is None else float(outflow_z),
        dem_dt=float(dem_dt),
        settle_time=0.0,
        duration=float(arrays["times"][-1]),
        frame_dt=frame_steps * float(dem_dt),
    )
    metadata = {
        "source": "imported",
        "dumps": str(dumps),
        "stl_files": [str(p) for p in stl_files],
        "first_timestep": first_timestep,
    }
    return Trajectory(**arrays, scene=scene, metadata=metadata)


def load_stl_wall(path: str | os.PathLike, name: str) -> Wall:
    """Load an STL file (ASCII or binary) as a static :class:`~granular_pyg.scenes.Wall`.

    Exactly coincident vertices are merged (STL stores three per triangle); the triangles are
    kept as they are, none added or removed.

    Args:
        path: the STL file, coordinates in metres.
        name: the wall's name (an identifier).

    Returns:
        The wall, ``vertices [V, 3]`` float64 (m), ``faces [F, 3]`` int64.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such STL file; check the --stl paths")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for bad files
        raise InputError(
            f"{path}: cannot read this STL file ({err}); export it again as ASCII or binary STL"
        ) from err
    faces = np.asarray(getattr(mesh, "faces", np.empty((0, 3))), np.int64)
    if faces.ndim != 2 or len(faces) == 0:
        raise InputError(f"{path}: the STL file holds no triangles; export the wall mesh again")
    vertices, inverse = np.unique(
        np.asarray(mesh.vertices, np.float64), axis=0, return_inverse=True
    )
    return Wall(name=name, vertices=vertices, faces=inverse.reshape(-1)[faces])


@reports_errors
def main(argv: Sequence[str] | None = None) -> Path:
    """Command line: convert dumps + STL files into one HDF5 trajectory; see the module doc."""
    parser = argparse.ArgumentParser(
        prog="python -m granular_pyg.dem.convert",
        description="Convert LIGGGHTS dump custom files and STL walls into a trajectory file.",
    )
    parser.add_argument("dumps", type=Path, help="dump file, or folder of dump files")
    parser.add_argument("--stl", nargs="*", default=[], type=Path, help="STL wall files (m)")
    parser.add_argument("--dem-dt", type=float, required=True, help="DEM time step (s)")
    parser.add_argument("--out", type=Path, required=True, help="output HDF5 file, e.g. traj.h5")
    parser.add_argument("--pattern", default="*", help="file-name glob in a dump folder")
    parser.add_argument(
        "--gravity", nargs=3, type=float, default=(0.0, 0.0, -9.81), help="m/s^2, 3 values"
    )
    parser.add_argument("--outflow-z", type=float, default=None, help="outflow height (m)")
    parser.add_argument(
        "--on-truncated", choices=("warn", "raise"), default="warn", help="truncated last frame"
    )
    args = parser.parse_args(argv)
    traj = trajectory_from_dumps(
        args.dumps,
        args.stl,
        args.dem_dt,
        gravity=tuple(args.gravity),
        outflow_z=args.outflow_z,
        on_truncated=args.on_truncated,
        pattern=args.pattern,
    )
    write_trajectory(traj, args.out)
    walls = ", ".join(f"{w.name} ({len(w.faces)} triangles)" for w in traj.scene.walls)
    print(
        f"wrote {args.out}: {traj.num_frames} frames x {traj.num_particles} particles, "
        f"frame_dt {traj.scene.frame_dt:.6g} s, duration {traj.scene.duration:.6g} s, "
        f"walls: {walls or 'none'}"
    )
    return args.out


def _identifier(stem: str) -> str:
    name = re.sub(r"[^0-9A-Za-z_]", "_", stem)
    return name if name and not name[0].isdigit() else f"wall_{name}"


def _unique(name: str, taken: set[str]) -> str:
    candidate, k = name, 2
    while candidate in taken:
        candidate, k = f"{name}_{k}", k + 1
    return candidate


def _floats(values) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


if __name__ == "__main__":
    main()
