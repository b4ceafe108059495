"""Import your own LIGGGHTS runs: ``dump custom`` files + STL walls -> a Trajectory file.

Command line::

    python -m granular_pyg.dem_import.convert DUMPS... --stl A.stl B.stl --dem-dt 2e-5 \\
        --out traj.h5
    python -m granular_pyg.dem_import.convert post/fill.dump post/discharge.dump \\
        --input in.hopper --mesh-dumps post/mesh --walls walls.yaml --out traj.h5

``DUMPS`` are dump files and/or folders of dump files (``--pattern`` selects names in a folder),
stitched on their TIMESTEPs (:mod:`granular_pyg.dem_import.stitch`). The dumps need the
columns ``id x y z vx vy vz radius`` (e.g. ``dump d all custom 125 post/dump id type x y z vx vy
vz radius``).

Frames that are not evenly spaced (a missing frame) are refused, naming the TIMESTEPs, unless
``--split-gaps`` is given: then each run of evenly spaced frames is written as its own
trajectory, ``--out run.h5`` -> ``run_part0.h5``, ``run_part1.h5``, ... (numbered in TIMESTEP
order over the parts written; every file checked like ``--out`` before any part is built, and
written atomically). Each part's times start at 0 at its first frame, as a single file's do
(its first TIMESTEP is in its metadata), and its walls are the run's walls re-based on that
frame (:func:`trajectories_from_dumps`). Runs of fewer than :data:`MIN_PART_FRAMES` frames are
skipped and parts of fewer than :data:`ROLLOUT_FRAMES` (too short to roll out from) written,
each with a ``warning:`` line on standard error.

What a dump does not hold comes from (each value from the first source that gives it; two
sources that give different values are refused, naming both):

* the command line: ``--dem-dt``, ``--gravity``, ``--outflow-z``, ``--kind``, ``--units``;
* ``--walls walls.yaml`` (:mod:`granular_pyg.dem_import.walls_config`): per STL its motion, removal
  time and units, and the scene's kind, outflow height, gravity and materials;
* ``--input in.run`` or ``--log log.liggghts`` (:mod:`granular_pyg.dem_import.liggghts_input`): time
  step, gravity, materials, density, which STL files the meshes read, their ``move/mesh``
  motions and ``unfix`` removals;
* ``--mesh-dumps`` (:mod:`granular_pyg.dem_import.mesh_dump`): every wall's pose per dump step,
  fitted to one constant rotation or translation, and the removal of a wall that vanishes from them.

Outflow as in the rollout (:mod:`granular_pyg.dem_import.outflow`): with ``outflow_z`` a particle
whose centre is below it is NaN from that frame on. Sanity checks
(:mod:`granular_pyg.dem_import.import_checks`) refuse non-finite atom values, walls in the wrong
units, and a DEM time step that does not fit the particles' motion.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from granular_pyg.cli import reports_errors
from granular_pyg.dem.dump import DumpFrame, frames_to_arrays
from granular_pyg.dem_import.import_checks import (
    check_dem_dt,
    check_frames_finite,
    check_wall_units,
)
from granular_pyg.dem_import.liggghts_input import RunScript, read_run_script
from granular_pyg.dem_import.mesh_dump import read_mesh_dumps
from granular_pyg.dem_import.outflow import apply_outflow, check_no_reappearance, count_vanished
from granular_pyg.dem_import.stitch import read_dump_runs, read_dumps
from granular_pyg.dem_import.wall_import import ImportedWall, import_walls, load_stl_wall
from granular_pyg.dem_import.walls_config import UNITS, WallsConfig, read_walls_config
from granular_pyg.errors import InputError
from granular_pyg.io import check_output
from granular_pyg.io.trajectory import Trajectory, write_trajectory
from granular_pyg.scenes.scene import (
    SCENE_KINDS,
    Materials,
    ParticleSpec,
    Scene,
    Wall,
    WallMotion,
)

__all__ = [
    "MIN_PART_FRAMES",
    "POSITIONAL",
    "ROLLOUT_FRAMES",
    "ConvertOptions",
    "DumpParts",
    "load_stl_wall",
    "main",
    "part_path",
    "trajectories_from_dumps",
    "trajectory_from_dumps",
]

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)
#: What the command line reads as a negative number, e-notation included (argparse's own
#: pattern takes ``--dem-dt -2e-5`` for an option and refuses it).
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

#: Fewest frames of a part ``--split-gaps`` writes; shorter runs are skipped with a warning.
MIN_PART_FRAMES = 3
#: Frames a rollout starts from: ``H + 1`` with the model's history ``H = 5``
#: (``conf/model/base.yaml``); a shorter part is written, with a warning.
ROLLOUT_FRAMES = 6

PathLike = str | os.PathLike


@dataclass(frozen=True)
class ConvertOptions:
    """What describes an imported run besides its dumps: the converter's options, in one place
    for :func:`trajectory_from_dumps`, :func:`trajectories_from_dumps` and the command line.

    Attributes:
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
        walls: a ``walls.yaml`` (path or parsed), see :mod:`granular_pyg.dem_import.walls_config`.
        input_script: the run's LIGGGHTS input script.
        log: the run's LIGGGHTS log (instead of ``input_script``).
        mesh_dumps: ``dump mesh/stl`` or ``mesh/vtk`` files and/or folders.
        mesh_pattern: glob for mesh dump file names in folders.
        kind: the scene kind (``hopper``, ``drum``, ``other``), or None (walls.yaml, else
            ``other``).
        units: units of the STL files (``m``, ``cm``, ``mm``) unless walls.yaml names them.
    """

    stl_files: Sequence[PathLike] = ()
    dem_dt: float | None = None
    gravity: tuple[float, float, float] | None = None
    outflow_z: float | None = None
    on_truncated: str = "warn"
    pattern: str = "*"
    walls: PathLike | WallsConfig | None = None
    input_script: PathLike | None = None
    log: PathLike | None = None
    mesh_dumps: Sequence[PathLike] = ()
    mesh_pattern: str = "*"
    kind: str | None = None
    units: str | None = None

    @classmethod
    def of(
        cls, options: ConvertOptions | None, args: tuple, keywords: dict[str, Any]
    ) -> ConvertOptions:
        """``options`` (or the defaults) with the positional ``args`` (in the order of
        :data:`POSITIONAL`) and the ``keywords`` set."""
        if len(args) > len(POSITIONAL):
            raise TypeError(f"at most {len(POSITIONAL)} positional options: {POSITIONAL}")
        given = dict(zip(POSITIONAL, args, strict=False))
        if set(given) & set(keywords):
            raise TypeError(f"given twice: {sorted(set(given) & set(keywords))}")
        return dataclasses.replace(options or cls(), **given, **keywords)


#: The options :func:`trajectory_from_dumps` also takes positionally, after the dumps.
POSITIONAL = ("stl_files", "dem_dt", "gravity", "outflow_z", "on_truncated", "pattern")


def trajectory_from_dumps(
    dumps: PathLike | Sequence[PathLike],
    *args: Any,
    options: ConvertOptions | None = None,
    **keywords: Any,
) -> Trajectory:
    """Build a Trajectory (with its Scene) from LIGGGHTS dumps and what describes the run.

    Args:
        dumps: ``dump custom`` files and/or folders of them, stitched on their TIMESTEPs.
        *args, options, **keywords: the :class:`ConvertOptions`: ``options`` with any given
            positionally (``stl_files, dem_dt, gravity, outflow_z, on_truncated, pattern``) or
            by keyword set.

    Returns:
        The trajectory. Its Scene is named walls.yaml's ``name``, else the kind if it is
        ``hopper`` or ``drum``, else ``"imported"``; it has ``ParticleSpec(count=N, radius=max
        radius, fill box = bounding box of the first frame)``, the dumps' box as domain (its
        floor at ``outflow_z``), ``frame_dt`` the recorded spacing, ``settle_time = 0`` and
        ``duration`` the last recorded time. Metadata: ``{"source": "imported", "dumps",
        "stl_files", "first_timestep", "walls": [per-wall sources], "sources": {value: where
        it came from}, "left_through_outflow", "never_present", "vanished"}`` (``vanished``:
        atoms that leave the dumps other than below ``outflow_z``, warned about).

    Raises:
        FileNotFoundError: a file does not exist.
        InputError: malformed inputs, sources that disagree, frames not evenly spaced (see
            :func:`trajectories_from_dumps` for one trajectory per evenly spaced run), or a
            failed sanity check; the message names the file, value and fix.
    """
    opts = ConvertOptions.of(options, args, keywords)
    found = _read_sources(opts)
    frames = read_dumps(dumps, on_truncated=opts.on_truncated, pattern=opts.pattern)
    (traj,) = _trajectories(found, [frames], frames, dumps, opts)
    return traj


@dataclass
class DumpParts:
    """What :func:`trajectories_from_dumps` made of dumps with gaps.

    Attributes:
        parts: one trajectory per run of at least ``min_frames`` evenly spaced frames, in
            TIMESTEP order.
        skipped: ``(first TIMESTEP, last TIMESTEP, frames)`` of each shorter run, left out.
    """

    parts: list[Trajectory]
    skipped: list[tuple[int, int, int]]


def trajectories_from_dumps(
    dumps: PathLike | Sequence[PathLike],
    *args: Any,
    options: ConvertOptions | None = None,
    min_frames: int = MIN_PART_FRAMES,
    check_parts: Callable[[int], None] | None = None,
    **keywords: Any,
) -> DumpParts:
    """One Trajectory per run of evenly spaced frames (``convert --split-gaps``), where
    :func:`trajectory_from_dumps` refuses a gap.

    The stitched frames are cut into runs
    (:func:`granular_pyg.dem_import.stitch.evenly_spaced_runs`); each run of at least
    ``min_frames`` frames becomes a trajectory built as
    :func:`trajectory_from_dumps` builds the whole: its times start at 0 at the part's first
    frame (the converter always counts recorded time from the first frame converted; the
    part's first TIMESTEP is its metadata's ``first_timestep``), its ``frame_dt`` is the part's
    spacing, and outflow, particles never present and the sanity checks are per part.

    The walls are resolved once for the whole run, as without gaps (``walls.yaml`` times count
    from the first dump frame; the script's motions and the mesh dumps, all of them, fitted to
    one motion, on TIMESTEPs), then re-based on each part's first frame: their vertices are
    the pose at that frame, their motion and removal times count from it, and a wall removed
    by then is left out of that part. An oscillation that has run a fractional number of
    periods by a part's start is refused (a WallMotion starts its sine at its start time).

    Args:
        dumps, *args, options, **keywords: as for :func:`trajectory_from_dumps`.
        min_frames: the fewest frames of a part; shorter runs are skipped (reported in
            ``skipped``).
        check_parts: called with the number of parts once the dumps are read and before any
            part is built (the command line checks its output files there).

    Returns:
        The parts and the skipped runs. Each part's metadata also holds ``split``: ``{"part":
        k, "parts": n, "timesteps": [first, last], "offset": the recorded time (s) of its
        first frame from the first dump frame}``.

    Raises:
        FileNotFoundError: a file does not exist.
        InputError: as :func:`trajectory_from_dumps` (except for the gaps), or no run of
            ``min_frames`` frames.
    """
    opts = ConvertOptions.of(options, args, keywords)
    found = _read_sources(opts)
    runs = read_dump_runs(dumps, on_truncated=opts.on_truncated, pattern=opts.pattern)
    kept = [r for r in runs if len(r) >= min_frames]
    skipped = [(r[0].timestep, r[-1].timestep, len(r)) for r in runs if len(r) < min_frames]
    if not kept:
        raise InputError(
            f"dumps: no run of at least {min_frames} evenly spaced frames to write (runs: "
            f"{', '.join(_timesteps(r[0].timestep, r[-1].timestep, len(r)) for r in runs)}); "
            "add the missing dump files"
        )
    if check_parts is not None:
        check_parts(len(kept))
    parts = _trajectories(found, kept, [f for r in runs for f in r], dumps, opts, split=True)
    return DumpParts(parts, skipped)


@dataclass
class _Sources:
    """walls.yaml, the run's script and the DEM time step, with where each value came from."""

    config: WallsConfig | None
    script: RunScript | None
    dt: float
    dt_from: str
    sources: dict[str, str]


def _read_sources(opts: ConvertOptions) -> _Sources:
    dem_dt, walls, input_script, log = opts.dem_dt, opts.walls, opts.input_script, opts.log
    if input_script is not None and log is not None:
        raise InputError("pass either the input script (--input) or the log (--log), not both")
    config = walls if isinstance(walls, WallsConfig) or walls is None else read_walls_config(walls)
    script_path = input_script if input_script is not None else log
    script = None
    if script_path is not None:
        script = read_run_script(script_path, is_log=log is not None)

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
    return _Sources(config, script, dt, dt_from, {"dem_dt": dt_from})


def _trajectories(
    found: _Sources,
    runs: list[list[DumpFrame]],
    all_frames: list[DumpFrame],
    dumps: PathLike | Sequence[PathLike],
    opts: ConvertOptions,
    split: bool = False,
) -> list[Trajectory]:
    """One trajectory per run of evenly spaced frames; ``all_frames`` are every frame read
    (the runs and any skipped ones), for the walls' time origin and the particle types."""
    stl_files, gravity, outflow_z = opts.stl_files, opts.gravity, opts.outflow_z
    mesh_dumps, mesh_pattern = opts.mesh_dumps, opts.mesh_pattern
    kind, units = opts.kind, opts.units
    config, script, dt = found.config, found.script, found.dt
    sources = dict(found.sources)
    check_frames_finite(all_frames)
    outflow, outflow_from = _pick(
        "outflow height",
        [(outflow_z, "--outflow-z"), _from_config(config, "outflow_z")],
    )
    if outflow is not None:
        sources["outflow_z"] = outflow_from
    particles = [_particles(frames, dt, found.dt_from, outflow, outflow_from) for frames in runs]

    origin = all_frames[0].timestep  # recorded time 0 of walls.yaml and the walls
    span = float((all_frames[-1].timestep - origin) * dt) if split else particles[0].duration
    mesh_frames = read_mesh_dumps(mesh_dumps, mesh_pattern) if mesh_dumps else []
    imported = import_walls(
        stl_files,
        dt,
        origin,
        config=config,
        script=script,
        mesh_frames=mesh_frames,
        units=units,
        duration=span,
    )

    offsets = [float((frames[0].timestep - origin) * dt) for frames in runs]
    part_walls = []
    for offset, part in zip(offsets, particles, strict=True):
        walls = [(w, _rebased(w, offset, dt)) for w in imported]
        walls = [(w, wall) for w, wall in walls if wall is not None]
        check_wall_units(
            [(wall.name, wall.vertices, str(w.stl), w.units) for w, wall in walls],
            part.arrays["positions"],
            part.radius,
        )
        part_walls.append(walls)

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
    materials, material_sources = _materials(config, script, all_frames)
    sources |= {f"materials.{k}": v for k, v in material_sources.items()}
    scene_kind, kind_from = _pick("kind", [(kind, "--kind"), _from_config(config, "kind")])
    sources["kind"] = kind_from or "default"
    if scene_kind is not None and scene_kind not in SCENE_KINDS:
        raise InputError(f"--kind: expected one of {SCENE_KINDS}, got {scene_kind!r}")
    scene_kind = scene_kind or "other"
    name = config.name if config is not None and config.name else None
    name = name or (scene_kind if scene_kind in ("hopper", "drum") else "imported")
    dump_paths = [dumps] if isinstance(dumps, (str, os.PathLike)) else list(dumps)

    out = []
    for k, (frames, part, walls) in enumerate(zip(runs, particles, part_walls, strict=True)):
        offset = offsets[k]
        arrays = part.arrays
        radius = part.radius
        first = frames[0]
        xyz = first.data[:, [first.columns.index(c) for c in ("x", "y", "z")]]
        if len(xyz):
            fill_lo, fill_hi = xyz.min(axis=0), xyz.max(axis=0)
        else:
            fill_lo, fill_hi = first.box[:, 0], first.box[:, 1]
        domain_lo, domain_hi = part.box[:, 0].copy(), part.box[:, 1].copy()
        if outflow is not None:
            domain_lo[2] = float(outflow)
        steps = np.diff(part.timesteps)
        frame_steps = int(steps[0]) if len(steps) else 1
        scene = Scene(
            name=name,
            kind=scene_kind,
            walls=[wall for _, wall in walls],
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
            duration=part.duration,
            frame_dt=frame_steps * float(dt),
        )
        metadata: dict[str, Any] = {
            "source": "imported",
            "dumps": [str(p) for p in dump_paths],
            "stl_files": [str(w.stl) for w, _ in walls],
            "first_timestep": part.first_timestep,
            "walls": [w.report() for w, _ in walls],
            "sources": sources,
            "left_through_outflow": part.left,
            "never_present": part.never,
            "vanished": part.vanished,
        }
        for key, value in (("walls_yaml", config), ("script", script), ("mesh_dumps", mesh_dumps)):
            if value:
                metadata[key] = (
                    [str(p) for p in value]
                    if isinstance(value, (list, tuple))
                    else str(getattr(value, "path", value))
                )
        if split:
            metadata["split"] = {
                "part": k,
                "parts": len(runs),
                "timesteps": [int(frames[0].timestep), int(frames[-1].timestep)],
                "offset": offset,
            }
        out.append(Trajectory(**arrays, scene=scene, metadata=metadata))
    return out


@dataclass
class _Particles:
    """The particle arrays of one run of frames, after outflow, and what was dropped."""

    arrays: dict[str, Any]
    first_timestep: int
    timesteps: np.ndarray
    box: np.ndarray
    duration: float
    radius: float
    left: int
    never: int
    vanished: int = 0


def _particles(
    frames: list[DumpFrame],
    dt: float,
    dt_from: str,
    outflow: float | None,
    outflow_from: str | None,
) -> _Particles:
    arrays = frames_to_arrays(frames, dt)
    first_timestep = arrays.pop("first_timestep")
    timesteps = np.array([f.timestep for f in frames], np.int64)
    check_dem_dt(arrays["positions"], arrays["velocities"], timesteps, dt, dt_from)
    box = _box(frames)
    left = 0
    if outflow is not None:
        if not (math.isfinite(outflow) and outflow < box[2, 1]):
            raise InputError(
                f"outflow_z: {outflow} ({outflow_from}) must be finite and below the box top "
                f"({box[2, 1]} m) of the dumps"
            )
        left = apply_outflow(arrays["positions"], arrays["velocities"], outflow)
    check_no_reappearance(arrays["positions"], arrays["ids"], timesteps)
    vanished = count_vanished(arrays["positions"], left, outflow, arrays["ids"], timesteps)
    keep = np.isfinite(arrays["positions"][..., 0]).any(axis=0)
    never = int((~keep).sum())
    if never:
        for key in ("positions", "velocities"):
            arrays[key] = arrays[key][:, keep]
        for key in ("radii", "ids"):
            arrays[key] = arrays[key][keep]
    duration = float(arrays["times"][-1])
    radius = float(np.max(arrays["radii"])) if len(arrays["radii"]) else 0.0
    return _Particles(
        arrays, first_timestep, timesteps, box, duration, radius, left, never, vanished
    )


def _rebased(imported: ImportedWall, offset: float, dt: float) -> Wall | None:
    """The wall (recorded time of the whole run) as a Scene wall whose recorded time 0 is
    ``offset`` (s): posed at ``offset``, its motion and removal ``offset`` earlier; None when it
    is removed by then."""
    wall = imported.wall
    if offset == 0:
        return wall
    removal = None
    if wall.removal_time is not None:
        removal = _since(wall.removal_time, offset, dt)
        if removal <= 0:
            return None
    m = wall.motion
    vertices = wall.vertices_at(offset)
    stop = None if m.stop_time is None else _since(m.stop_time, offset, dt)
    if m.kind == "static" or (stop is not None and stop <= 0):
        motion = WallMotion("static")
    else:
        start = _since(m.start_time, offset, dt)
        if m.kind == "oscillation" and start < 0:
            cycles = -start / m.period
            if abs(cycles - round(cycles)) > 1e-9:
                raise InputError(
                    f"wall {wall.name} ({imported.stl}): its oscillation ({imported.motion_from}) "
                    f"has run {cycles:.6g} periods by the part that starts at t = {offset:.6g} s, "
                    "not a whole number: a WallMotion starts its sine at its start time; convert "
                    "without --split-gaps"
                )
            vertices = wall.vertices  # whole periods: back at the mesh pose
        motion = dataclasses.replace(m, start_time=max(0.0, start), stop_time=stop)
    return Wall(wall.name, vertices, wall.faces, motion, removal)


def _since(t: float, offset: float, dt: float) -> float:
    """``t - offset`` (s), snapped to a whole number of DEM steps when within round-off of
    one."""
    x = t - offset
    steps = x / dt
    return round(steps) * dt if abs(steps - round(steps)) < 1e-6 else x


def _timesteps(first: int, last: int, frames: int) -> str:
    """``"TIMESTEPs 700..800 (2 frames)"``, or ``"TIMESTEP 700 (1 frame)"``."""
    if frames == 1:
        return f"TIMESTEP {first} (1 frame)"
    return f"TIMESTEPs {first}..{last} ({frames} frames)"


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
def main(argv: Sequence[str] | None = None) -> Path | list[Path]:
    """Command line: convert dumps + walls into one HDF5 trajectory (with ``--split-gaps``,
    one per run of evenly spaced frames); see the module doc. Returns the file(s) written."""
    parser = argparse.ArgumentParser(
        prog="python -m granular_pyg.dem_import.convert",
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
    parser.add_argument(
        "--split-gaps",
        action="store_true",
        help="instead of refusing a missing frame, write each run of evenly spaced frames as its "
        "own trajectory: --out run.h5 -> run_part0.h5, run_part1.h5, ...",
    )
    parser._negative_number_matcher = NEGATIVE_NUMBER  # -2e-5 is a value, not an option
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
    options = ConvertOptions(
        stl_files=args.stl,
        dem_dt=args.dem_dt,
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
    if args.split_gaps:
        return _split_main(args, inputs, options)
    out = check_output(
        args.out, inputs, args.overwrite, option="--out", overwrite_option="--overwrite"
    )
    traj = trajectory_from_dumps(args.dumps, options=options)
    write_trajectory(traj, out)
    walls = ", ".join(_describe(w) for w in traj.scene.walls)
    print(
        f"wrote {out}: {traj.num_frames} frames x {traj.num_particles} particles, "
        f"frame_dt {traj.scene.frame_dt:.6g} s, duration {traj.scene.duration:.6g} s, "
        f"kind {traj.scene.kind}, walls: {walls or 'none'}"
    )
    return out


def part_path(out: PathLike, k: int) -> Path:
    """The file of part ``k`` of ``--out`` with ``--split-gaps``: ``run.h5`` ->
    ``run_part<k>.h5``."""
    out = Path(out)
    return out.with_name(f"{out.stem}_part{k}{out.suffix}")


def _split_main(args: argparse.Namespace, inputs: list, options: ConvertOptions) -> list[Path]:
    """``--split-gaps``: every part's file checked (none an input, none existing without
    --overwrite) once the dumps are read and before any part is built; each written
    atomically."""
    check = {"option": "--out", "overwrite_option": "--overwrite"}
    check_output(args.out, inputs, True, **check)  # its folder, before the dumps are read
    outs: list[Path] = []

    def check_parts(count: int) -> None:
        outs[:] = [
            check_output(part_path(args.out, k), inputs, args.overwrite, **check)
            for k in range(count)
        ]

    result = trajectories_from_dumps(args.dumps, options=options, check_parts=check_parts)
    if result.skipped:
        runs = ", ".join(_timesteps(*run) for run in result.skipped)
        print(
            f"warning: --split-gaps: skipped {len(result.skipped)} run(s) of evenly spaced "
            f"frames shorter than {MIN_PART_FRAMES} frames: {runs}",
            file=sys.stderr,
        )
    short = [
        f"{out} ({traj.num_frames} frames)"
        for out, traj in zip(outs, result.parts, strict=True)
        if traj.num_frames < ROLLOUT_FRAMES
    ]
    if short:
        print(
            f"warning: --split-gaps: {', '.join(short)}: fewer than the {ROLLOUT_FRAMES} frames "
            "(H + 1) a rollout starts from; written as data, too short to roll out from",
            file=sys.stderr,
        )
    for out, traj in zip(outs, result.parts, strict=True):
        write_trajectory(traj, out)
    described = [", ".join(_describe(w) for w in t.scene.walls) or "none" for t in result.parts]
    same_walls = len(set(described)) == 1
    parts = []
    for out, traj, walls in zip(outs, result.parts, described, strict=True):
        first, last = traj.metadata["split"]["timesteps"]
        parts.append(
            f"{out}: {traj.num_frames} frames x {traj.num_particles} particles, "
            f"TIMESTEPs {first}..{last}, frame_dt {traj.scene.frame_dt:.6g} s, "
            f"duration {traj.scene.duration:.6g} s" + ("" if same_walls else f", walls: {walls}")
        )
    kind = result.parts[0].scene.kind
    print(
        f"wrote {len(outs)} part(s): {'; '.join(parts)}; kind {kind}"
        + (f", walls: {described[0]}" if same_walls else "")
    )
    return outs


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
