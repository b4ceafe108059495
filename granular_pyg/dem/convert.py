"""Import your own LIGGGHTS runs: ``dump custom`` files + STL walls -> a Trajectory file.

Command line::

    python -m granular_pyg.dem.convert DUMPS... --stl A.stl B.stl --dem-dt 2e-5 --out traj.h5
    python -m granular_pyg.dem.convert post/fill.dump post/discharge.dump --input in.hopper \\
        --mesh-dumps post/mesh --walls walls.yaml --out traj.h5

``DUMPS`` are dump files and/or folders of dump files (``--pattern`` selects names in a folder),
stitched on their TIMESTEPs (:mod:`granular_pyg.dem.stitch`). The dumps need the columns ``id x
y z vx vy vz radius`` (e.g. ``dump d all custom 125 post/dump id type x y z vx vy vz radius``).

What a dump does not hold comes from (each value from the first source that gives it; two
sources that give different values are refused, naming both):

* the command line: ``--dem-dt``, ``--gravity``, ``--outflow-z``, ``--kind``, ``--units``;
* ``--walls walls.yaml`` (:mod:`granular_pyg.dem.walls_config`): per STL its motion, removal
  time and units, and the scene's kind, outflow height, gravity and materials;
* ``--input in.run`` or ``--log log.liggghts`` (:mod:`granular_pyg.dem.liggghts_input`): time
  step, gravity, materials, density, which STL files the meshes read, their ``move/mesh``
  motions and ``unfix`` removals;
* ``--mesh-dumps`` (:mod:`granular_pyg.dem.mesh_dump`): every wall's pose per dump step, fitted
  to one constant rotation or translation, and the removal of a wall that vanishes from them.

Outflow as in the rollout (:mod:`granular_pyg.dem.outflow`): with ``outflow_z`` a particle
whose centre is below it is NaN from that frame on. Sanity checks
(:mod:`granular_pyg.dem.import_checks`) refuse non-finite atom values, walls in the wrong units,
and a DEM time step that does not fit the particles' motion.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from granular_pyg.cli import reports_errors
from granular_pyg.dem.dump import frames_to_arrays
from granular_pyg.dem.import_checks import (
    check_dem_dt,
    check_frames_finite,
    check_wall_units,
)
from granular_pyg.dem.liggghts_input import RunScript, read_run_script
from granular_pyg.dem.mesh_dump import read_mesh_dumps
from granular_pyg.dem.outflow import apply_outflow, check_no_reappearance
from granular_pyg.dem.stitch import read_dumps
from granular_pyg.dem.wall_import import import_walls, load_stl_wall
from granular_pyg.dem.walls_config import UNITS, WallsConfig, read_walls_config
from granular_pyg.errors import InputError
from granular_pyg.io import check_output
from granular_pyg.io.trajectory import Trajectory, write_trajectory
from granular_pyg.scenes.scene import SCENE_KINDS, Materials, ParticleSpec, Scene

__all__ = ["load_stl_wall", "main", "trajectory_from_dumps"]

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)

PathLike = str | os.PathLike


def trajectory_from_dumps(
    dumps: PathLike | Sequence[PathLike],
    stl_files: Sequence[PathLike] = (),
    dem_dt: float | None = None,
    gravity: tuple[float, float, float] | None = None,
    outflow_z: float | None = None,
    on_truncated: str = "warn",
    pattern: str = "*",
    *,
    walls: PathLike | WallsConfig | None = None,
    input_script: PathLike | None = None,
    log: PathLike | None = None,
    mesh_dumps: Sequence[PathLike] = (),
    mesh_pattern: str = "*",
    kind: str | None = None,
    units: str | None = None,
) -> Trajectory:
    """Build a Trajectory (with its Scene) from LIGGGHTS dumps and what describes the run.

    Args:
        dumps: ``dump custom`` files and/or folders of them, stitched on their TIMESTEPs.
        stl_files: STL wall files, named after their file stems sanitised to identifiers
            (``hopper-left.stl`` -> ``hopper_left``); static unless a source moves them.
        dem_dt: the run's DEM time step (s); times are ``(timestep - first) * dem_dt``. None to
            take it from ``input_script`` / ``log``.
        gravity: ``[3]`` gravitational acceleration (m/s^2), or None (walls.yaml, the script,
            else ``(0, 0, -9.81)``).
        outflow_z: height (m) below which particles leave for good, or None (walls.yaml, else
            a closed scene); becomes the scene's ``domain_lo`` z.
        on_truncated: ``"warn"`` drops a truncated last frame with a warning, ``"raise"`` fails.
        pattern: glob for dump file names in folders.
        walls: a ``walls.yaml`` (path or parsed), see :mod:`granular_pyg.dem.walls_config`.
        input_script: the run's LIGGGHTS input script.
        log: the run's LIGGGHTS log (instead of ``input_script``).
        mesh_dumps: ``dump mesh/stl`` or ``mesh/vtk`` files and/or folders.
        mesh_pattern: glob for mesh dump file names in folders.
        kind: the scene kind (``hopper``, ``drum``, ``other``), or None (walls.yaml, else
            ``other``).
        units: units of the STL files (``m``, ``cm``, ``mm``) unless walls.yaml names them.

    Returns:
        The trajectory. Its Scene is named walls.yaml's ``name``, else the kind if it is
        ``hopper`` or ``drum``, else ``"imported"``; it has ``ParticleSpec(count=N, radius=max
        radius, fill box = bounding box of the first frame)``, the dumps' box as domain (its
        floor at ``outflow_z``), ``frame_dt`` the recorded spacing, ``settle_time = 0`` and
        ``duration`` the last recorded time. Metadata: ``{"source": "imported", "dumps",
        "stl_files", "first_timestep", "walls": [per-wall sources], "sources": {value: where
        it came from}, "left_through_outflow", "never_present"}``.

    Raises:
        FileNotFoundError: a file does not exist.
        InputError: malformed inputs, sources that disagree, or a failed sanity check; the
            message names the file, value and fix.
    """
    if input_script is not None and log is not None:
        raise InputError("pass either the input script (--input) or the log (--log), not both")
    config = walls if isinstance(walls, WallsConfig) or walls is None else read_walls_config(walls)
    script_path = input_script if input_script is not None else log
    script = None
    if script_path is not None:
        script = read_run_script(script_path, is_log=log is not None)
    sources: dict[str, str] = {}

    script_dt = None
    if script is not None and not (dem_dt is not None and "timestep" in script.problems):
        script_dt = script.timestep  # an unreadable one matters only without --dem-dt
    dt, dt_from = _pick("time step", [(dem_dt, "--dem-dt"), script_dt])
    if dt is None:
        raise InputError(
            "--dem-dt: the run's DEM time step (s) is required (or read it from the run's "
            "script with --input/--log)"
        )
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise InputError(f"dem_dt: expected the run's positive DEM time step (s), got {dt!r}")
    sources["dem_dt"] = dt_from

    frames = read_dumps(dumps, on_truncated=on_truncated, pattern=pattern)
    check_frames_finite(frames)
    arrays = frames_to_arrays(frames, dt)
    first_timestep = arrays.pop("first_timestep")
    timesteps = np.array([f.timestep for f in frames], np.int64)
    check_dem_dt(arrays["positions"], arrays["velocities"], timesteps, dt, dt_from)

    outflow, outflow_from = _pick(
        "outflow height",
        [(outflow_z, "--outflow-z"), _from_config(config, "outflow_z")],
    )
    box = _box(frames)
    left = 0
    if outflow is not None:
        if not (math.isfinite(outflow) and outflow < box[2, 1]):
            raise InputError(
                f"outflow_z: {outflow} ({outflow_from}) must be finite and below the box top "
                f"({box[2, 1]} m) of the dumps"
            )
        left = apply_outflow(arrays["positions"], arrays["velocities"], outflow)
        sources["outflow_z"] = outflow_from
    check_no_reappearance(arrays["positions"], arrays["ids"], timesteps)
    keep = np.isfinite(arrays["positions"][..., 0]).any(axis=0)
    never = int((~keep).sum())
    if never:
        for key in ("positions", "velocities"):
            arrays[key] = arrays[key][:, keep]
        for key in ("radii", "ids"):
            arrays[key] = arrays[key][keep]

    duration = float(arrays["times"][-1])
    mesh_frames = read_mesh_dumps(mesh_dumps, mesh_pattern) if mesh_dumps else []
    imported = import_walls(
        stl_files,
        dt,
        first_timestep,
        config=config,
        script=script,
        mesh_frames=mesh_frames,
        units=units,
        duration=duration,
    )
    radius = float(np.max(arrays["radii"])) if len(arrays["radii"]) else 0.0
    check_wall_units(
        [(w.wall.name, w.wall.vertices, str(w.stl), w.units) for w in imported],
        arrays["positions"],
        radius,
    )

    g, g_from = _pick(
        "gravity",
        [
            (None if gravity is None else tuple(float(v) for v in gravity), "--gravity"),
            _from_config(config, "gravity"),
            script.gravity if script is not None else None,
        ],
    )
    if g is None and script is not None and "gravity" in script.problems:
        raise InputError(script.problems["gravity"])
    sources["gravity"] = g_from or "default"
    materials, material_sources = _materials(config, script, frames)
    sources |= {f"materials.{k}": v for k, v in material_sources.items()}
    scene_kind, kind_from = _pick("kind", [(kind, "--kind"), _from_config(config, "kind")])
    sources["kind"] = kind_from or "default"
    if scene_kind is not None and scene_kind not in SCENE_KINDS:
        raise InputError(f"--kind: expected one of {SCENE_KINDS}, got {scene_kind!r}")
    scene_kind = scene_kind or "other"
    name = config.name if config is not None and config.name else None
    name = name or (scene_kind if scene_kind in ("hopper", "drum") else "imported")

    first = frames[0]
    xyz = first.data[:, [first.columns.index(c) for c in ("x", "y", "z")]]
    if len(xyz):
        fill_lo, fill_hi = xyz.min(axis=0), xyz.max(axis=0)
    else:
        fill_lo, fill_hi = first.box[:, 0], first.box[:, 1]
    domain_lo, domain_hi = box[:, 0].copy(), box[:, 1].copy()
    if outflow is not None:
        domain_lo[2] = float(outflow)
    steps = np.diff(timesteps)
    frame_steps = int(steps[0]) if len(steps) else 1
    scene = Scene(
        name=name,
        kind=scene_kind,
        walls=[w.wall for w in imported],
        particles=ParticleSpec(
            count=len(arrays["ids"]),
            radius=radius,
            fill_lo=_floats(fill_lo),
            fill_hi=_floats(fill_hi),
        ),
        materials=materials,
        gravity=_floats(g if g is not None else DEFAULT_GRAVITY),
        domain_lo=_floats(domain_lo),
        domain_hi=_floats(domain_hi),
        outflow_z=None if outflow is None else float(outflow),
        dem_dt=float(dt),
        settle_time=0.0,
        duration=duration,
        frame_dt=frame_steps * float(dt),
    )
    dump_paths = [dumps] if isinstance(dumps, (str, os.PathLike)) else list(dumps)
    metadata: dict[str, Any] = {
        "source": "imported",
        "dumps": [str(p) for p in dump_paths],
        "stl_files": [str(w.stl) for w in imported],
        "first_timestep": first_timestep,
        "walls": [w.report() for w in imported],
        "sources": sources,
        "left_through_outflow": left,
        "never_present": never,
    }
    for key, value in (("walls_yaml", config), ("script", script), ("mesh_dumps", mesh_dumps)):
        if value:
            metadata[key] = (
                [str(p) for p in value]
                if isinstance(value, (list, tuple))
                else str(getattr(value, "path", value))
            )
    return Trajectory(**arrays, scene=scene, metadata=metadata)


def _pick(what: str, given: list[tuple[Any, str] | None]) -> tuple[Any, str | None]:
    """The first given value and its source; another source that gives a different value is
    refused, naming both."""
    found = [(v, src) for item in given if item is not None for v, src in [item] if v is not None]
    if not found:
        return None, None
    value, source = found[0]
    for other, other_source in found[1:]:
        if not _same_value(value, other):
            raise InputError(
                f"{what}: {value!r} from {source} disagrees with {other!r} from {other_source}; "
                "give it once (drop one of them)"
            )
    return value, source


def _same_value(a: Any, b: Any) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return bool(np.allclose(np.asarray(a, float), np.asarray(b, float), rtol=1e-9, atol=1e-12))


def _from_config(config: WallsConfig | None, key: str) -> tuple[Any, str] | None:
    if config is None or getattr(config, key) is None:
        return None
    return getattr(config, key), f"{config.path}: {key}"


def _box(frames) -> np.ndarray:
    """``[3, 2]`` the union of the frames' box bounds (m)."""
    boxes = np.stack([f.box for f in frames])
    return np.stack([boxes[:, :, 0].min(0), boxes[:, :, 1].max(0)], axis=1)


def _materials(
    config: WallsConfig | None, script: RunScript | None, frames
) -> tuple[Materials, dict[str, str]]:
    """The Materials from walls.yaml and the script (defaults for the rest), and their
    sources."""
    given = dict(config.materials) if config is not None else {}
    where = {k: f"{config.path}: materials.{k}" for k in given} if config is not None else {}
    read: dict[str, tuple[float, str]] = {}
    if script is not None:
        types = {int(t) for f in frames if "type" in f.columns for t in f.column("type")}
        particle_types = script.particle_types(types)
        try:
            read = script.materials(particle_types)
        except InputError:  # walls.yaml may settle what the script leaves open
            read = script.materials(particle_types, skip=frozenset(given))
    for key, (value, line) in read.items():
        if key in given and not _same_value(given[key], value):
            raise InputError(
                f"materials.{key}: {given[key]!r} from {where[key]} disagrees with {value!r} "
                f"from {line}; give it once (drop one of them)"
            )
        if key not in given:
            given[key], where[key] = value, line
    fields = dataclasses.asdict(Materials()) | given
    sources = {k: where.get(k, "default") for k in fields}
    return Materials(**fields), sources


@reports_errors
def main(argv: Sequence[str] | None = None) -> Path:
    """Command line: convert dumps + walls into one HDF5 trajectory; see the module doc."""
    parser = argparse.ArgumentParser(
        prog="python -m granular_pyg.dem.convert",
        description="Convert LIGGGHTS dump custom files and STL walls into a trajectory file.",
    )
    parser.add_argument(
        "dumps", nargs="+", type=Path, help="dump files and/or folders, stitched in time"
    )
    parser.add_argument("--stl", nargs="*", default=[], type=Path, help="STL wall files")
    parser.add_argument("--dem-dt", type=float, default=None, help="DEM time step (s)")
    parser.add_argument("--out", type=Path, required=True, help="output HDF5 file, e.g. traj.h5")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument("--pattern", default="*", help="file-name glob in a dump folder")
    parser.add_argument("--gravity", nargs=3, type=float, default=None, help="m/s^2, 3 values")
    parser.add_argument("--outflow-z", type=float, default=None, help="outflow height (m)")
    parser.add_argument(
        "--on-truncated", choices=("warn", "raise"), default="warn", help="truncated last frame"
    )
    parser.add_argument("--walls", type=Path, default=None, help="walls.yaml: motions, removals")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--input", type=Path, default=None, help="the run's input script")
    source.add_argument("--log", type=Path, default=None, help="the run's log (log.liggghts)")
    parser.add_argument(
        "--mesh-dumps", nargs="+", type=Path, default=[], help="dump mesh/stl files or folders"
    )
    parser.add_argument("--mesh-pattern", default="*", help="file-name glob in a mesh folder")
    parser.add_argument("--kind", choices=SCENE_KINDS, default=None, help="scene kind")
    parser.add_argument("--units", choices=tuple(UNITS), default=None, help="STL units")
    args = parser.parse_args(argv)

    config = read_walls_config(args.walls) if args.walls is not None else None
    named: list[Path] = [w.file for w in config.walls] if config is not None else []
    script_path = args.input or args.log
    if script_path is not None:
        named += [
            m.file for m in read_run_script(script_path, args.log is not None).meshes.values()
        ]
    inputs = [
        *args.dumps,
        *args.stl,
        *named,
        args.walls,
        script_path,
        *args.mesh_dumps,
    ]
    out = check_output(
        args.out, inputs, args.overwrite, option="--out", overwrite_option="--overwrite"
    )
    traj = trajectory_from_dumps(
        args.dumps,
        args.stl,
        args.dem_dt,
        gravity=None if args.gravity is None else tuple(args.gravity),
        outflow_z=args.outflow_z,
        on_truncated=args.on_truncated,
        pattern=args.pattern,
        walls=config,
        input_script=args.input,
        log=args.log,
        mesh_dumps=args.mesh_dumps,
        mesh_pattern=args.mesh_pattern,
        kind=args.kind,
        units=args.units,
    )
    write_trajectory(traj, out)
    walls = ", ".join(_describe(w) for w in traj.scene.walls)
    print(
        f"wrote {out}: {traj.num_frames} frames x {traj.num_particles} particles, "
        f"frame_dt {traj.scene.frame_dt:.6g} s, duration {traj.scene.duration:.6g} s, "
        f"kind {traj.scene.kind}, walls: {walls or 'none'}"
    )
    return out


def _describe(wall) -> str:
    parts = [f"{len(wall.faces)} triangles"]
    m = wall.motion
    if m.kind == "rotation":
        parts.append(f"rotation {m.omega:.6g} rad/s")
    elif m.kind != "static":
        parts.append(m.kind)
    if wall.removal_time is not None:
        parts.append(f"removed at {wall.removal_time:.6g} s")
    return f"{wall.name} ({', '.join(parts)})"


def _floats(values) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


if __name__ == "__main__":
    main()
