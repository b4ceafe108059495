"""The walls of an imported run, from every source that describes them, checked against each
other and expressed in recorded time.

Sources, in order of precedence (a value is taken from the first that gives it, and every other
source that gives it must agree, else :class:`~granular_pyg.errors.InputError` names both):

1. ``walls.yaml`` (:mod:`granular_pyg.dem_import.walls_config`): motion and removal in recorded
   time, the STL being the wall at recorded time 0;
2. the run's input script or log (:mod:`granular_pyg.dem_import.liggghts_input`): which STL files
   the meshes read (with their ``scale``/``move``/``rotate``), ``move/mesh`` motions and ``unfix``
   removals, at DEM steps;
3. the mesh dumps (:mod:`granular_pyg.dem_import.mesh_dump`): the pose of every wall at every dump
   step, fitted to one constant motion, and the first dump step without a wall (its removal).

A wall is identified by its STL file (the same file named by ``--stl``, ``walls.yaml`` and the
script, matched by path, else by file name). Internally motions run on absolute time
``tau = TIMESTEP * dem_dt`` from a base pose of the loaded mesh; the Scene's walls are re-based
on the first dump frame ``tau0``: their vertices are the pose at ``tau0`` and their motions start
``tau0`` later (a motion already running keeps running from recorded time 0).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from granular_pyg.dem_import.import_checks import check_wall_coordinates
from granular_pyg.dem_import.liggghts_input import MeshFix, RunScript
from granular_pyg.dem_import.mesh_dump import (
    MeshFrame,
    MeshRef,
    WallTrack,
    motion_from_track,
    track_walls,
)
from granular_pyg.dem_import.rigid_fit import IDENTITY, Pose, dump_tolerance, pose_deviation
from granular_pyg.dem_import.walls_config import WallEntry, WallsConfig, unit_scale
from granular_pyg.errors import InputError
from granular_pyg.scenes.mesh_scene import read_stl
from granular_pyg.scenes.scene import Wall, WallMotion

__all__ = ["ImportedWall", "import_walls", "load_stl_wall"]


#: Precedence of the sources (lower first).
YAML, SCRIPT, MESH_DUMPS = 0, 1, 2


@dataclass
class _Motion:
    """A motion in absolute time: ``x(tau) = motion.pose(tau)(base(x_loaded))``, valid from
    ``valid_from`` (s) on; ``rank`` is its source's precedence."""

    base: Pose
    motion: WallMotion
    source: str
    rank: int
    valid_from: float = 0.0

    def pose(self, tau: float) -> Pose:
        rot, shift = self.motion.pose(tau)
        return self.base.then(Pose(rot, shift))


@dataclass
class _Removal:
    """A removal time in absolute time (s; inf: never removed) with its source."""

    tau: float
    source: str
    rank: int


@dataclass
class ImportedWall:
    """One wall of the imported Scene and where its description came from.

    Attributes:
        wall: the Scene's wall (recorded time).
        stl: the STL file.
        units: the STL's units.
        motion_from: the source of its motion (``"static"`` when none gives one).
        removal_from: the source of its removal time, or None.
    """

    wall: Wall
    stl: Path
    units: str
    motion_from: str
    removal_from: str | None

    def report(self) -> dict:
        """JSON-able summary for the trajectory's metadata."""
        return {
            "name": self.wall.name,
            "stl": str(self.stl),
            "units": self.units,
            "motion_from": self.motion_from,
            "removal_from": self.removal_from,
        }


@dataclass
class _Entry:
    """A mesh as the sources name it."""

    file: Path
    cli: Path | None = None
    yaml: WallEntry | None = None
    mesh: MeshFix | None = None
    name: str = ""
    units: str = "m"
    triangles: np.ndarray | None = None  # [F, 3, 3] as loaded (m)
    vertices: np.ndarray | None = None  # [V, 3] as loaded (m)
    faces: np.ndarray | None = None
    motions: list[_Motion] = field(default_factory=list)
    removals: list[_Removal] = field(default_factory=list)
    track: WallTrack | None = None

    @property
    def is_wall(self) -> bool:
        return self.mesh is None or self.mesh.is_wall

    @property
    def what(self) -> str:
        return f"wall {self.name} ({self.file})"


def load_stl_wall(path: str | os.PathLike, name: str) -> Wall:
    """Load an STL file (ASCII or binary) as a static :class:`~granular_pyg.scenes.Wall`.

    Exactly coincident vertices are merged (STL stores three per triangle); the triangles are
    kept as they are, in file order, none added or removed.

    Args:
        path: the STL file.
        name: the wall's name (an identifier).

    Returns:
        The wall, ``vertices [V, 3]`` float64 (the file's units), ``faces [F, 3]`` int64.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such STL file; check the --stl paths")
    vertices, faces = read_stl(path)
    return Wall(name=name, vertices=vertices, faces=faces)


def import_walls(
    stl_files: Sequence[str | os.PathLike],
    dem_dt: float,
    first_timestep: int,
    config: WallsConfig | None = None,
    script: RunScript | None = None,
    mesh_frames: Sequence[MeshFrame] = (),
    units: str | None = None,
    duration: float = 0.0,
) -> list[ImportedWall]:
    """Build the Scene's walls of an imported run.

    Args:
        stl_files: STL files given on the command line (``--stl``).
        dem_dt: the DEM time step (s).
        first_timestep: TIMESTEP of the first particle frame (recorded time 0).
        config: the parsed ``walls.yaml``, or None.
        script: the parsed input script or log, or None.
        mesh_frames: mesh dumps (:func:`granular_pyg.dem_import.mesh_dump.read_mesh_dumps`).
        units: ``--units``: the STL files' units unless ``walls.yaml`` names them per wall.
        duration: the recorded time (s); motions from two sources are compared over it.

    Returns:
        The walls in the order: the script's meshes, then ``--stl``, then ``walls.yaml``;
        meshes that are no walls (not in a ``wall/gran`` list) and walls removed before
        recorded time 0 are left out.

    Raises:
        FileNotFoundError: an STL file does not exist.
        InputError: sources that disagree (naming both and the value), a motion no single
            WallMotion can express, an STL with vertices beyond 1 km, and the errors of the
            mesh dump tracking.
    """
    tau0 = first_timestep * dem_dt
    entries = _entries(stl_files, config, script)
    taken: set[str] = set()
    for entry in entries:
        stem = entry.yaml.name if entry.yaml is not None and entry.yaml.name else entry.file.stem
        entry.name = _unique(_identifier(stem), taken)
        taken.add(entry.name)
        _load(entry, config, units)

    if mesh_frames:
        refs = [MeshRef(e.name, e.triangles, e.is_wall) for e in entries]
        tracks = track_walls(mesh_frames, refs)
        for entry in entries:
            track = tracks[entry.name]
            if not track.timesteps or not entry.is_wall:
                continue
            points = entry.triangles.reshape(-1, 3)
            base, motion = motion_from_track(track, points, dem_dt)
            if track.timesteps[0] > first_timestep and motion.kind != "static":
                raise InputError(
                    f"wall {entry.name}: the mesh dumps start at TIMESTEP {track.timesteps[0]} "
                    f"({track.sources[0]}), after the first particle frame (TIMESTEP "
                    f"{first_timestep}), and it moves: its pose before is unknown; dump the "
                    "meshes from the first frame on, or give its motion (--walls, --input)"
                )
            valid_from = track.timesteps[0] * dem_dt
            entry.motions.append(_Motion(base, motion, "mesh dumps", MESH_DUMPS, valid_from))
            entry.track = track
            if track.removed_at is not None:
                entry.removals.append(_Removal(track.removed_at * dem_dt, "mesh dumps", MESH_DUMPS))

    out = []
    for entry in entries:
        if not entry.is_wall:
            continue
        _script_sources(entry, script, dem_dt)
        if entry.yaml is not None:
            _yaml_sources(entry, tau0)
        imported = _resolve(entry, dem_dt, tau0, duration)
        if imported is None:
            warnings.warn(
                f"{entry.what} is removed before the first dump frame (TIMESTEP "
                f"{first_timestep}); it is left out of the Scene",
                stacklevel=2,
            )
        else:
            out.append(imported)
    return out


# --- gathering -------------------------------------------------------------------------------


def _entries(
    stl_files: Sequence[str | os.PathLike],
    config: WallsConfig | None,
    script: RunScript | None,
) -> list[_Entry]:
    entries: list[_Entry] = []
    if script is not None:
        for key, problem in script.problems.items():
            if key.startswith("mesh:"):
                raise InputError(problem)
        for mesh in script.meshes.values():
            entries.append(_Entry(file=mesh.file, mesh=mesh))
        if entries and not any(e.mesh.is_wall for e in entries):
            for e in entries:  # no wall/gran list read: every mesh is a wall
                e.mesh.is_wall = True
    for given in stl_files:
        entry = _match([e for e in entries if e.cli is None], Path(given), "--stl")
        if entry is None:
            entries.append(_Entry(file=Path(given), cli=Path(given)))
        else:
            entry.cli = Path(given)
            entry.file = Path(given)
    for wall in config.walls if config is not None else []:
        entry = _match([e for e in entries if e.yaml is None], wall.file, wall.where)
        if entry is None:
            entries.append(_Entry(file=wall.file, yaml=wall))
        else:
            entry.yaml = wall
            if not entry.file.is_file() and wall.file.is_file():
                entry.file = wall.file
    return entries


def _match(entries: list[_Entry], path: Path, where: str) -> _Entry | None:
    """The entry (of another source) of the same STL file: the same path, else the only one
    of that file name."""
    for entry in entries:
        if _same(entry.file, path):
            return entry
    named = [e for e in entries if e.file.name == path.name]
    if len(named) > 1:
        raise InputError(
            f"{where}: {path} matches several meshes by file name "
            f"({', '.join(str(e.file) for e in named)}); give its full path"
        )
    return named[0] if named else None


def _same(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def _load(entry: _Entry, config: WallsConfig | None, units: str | None) -> None:
    """Load the STL, in metres and with the script's load transforms."""
    if not entry.file.is_file():
        where = f" (named at {entry.mesh.where})" if entry.mesh is not None else ""
        raise FileNotFoundError(
            f"{entry.file}: no such STL file{where}; pass it with --stl or fix the path"
        )
    given = [
        (entry.yaml.units, f"{entry.yaml.where}.units")
        if entry.yaml and entry.yaml.units
        else None,
        (units, "--units") if units else None,
        (config.units, f"{config.path}: units") if config is not None and config.units else None,
    ]
    chosen = next((g for g in given if g is not None), None)
    if units and config is not None and config.units and units != config.units:
        raise InputError(
            f"--units {units} disagrees with 'units: {config.units}' in {config.path}; give it once"
        )
    entry.units = chosen[0] if chosen else "m"
    if entry.mesh is not None and chosen is not None and entry.units != "m":
        raise InputError(
            f"{chosen[1]}: {entry.units} for {entry.file}, but the run reads this STL itself "
            f"({entry.mesh.where}) in metres (with any 'scale' it gives); drop the units"
        )
    wall = load_stl_wall(entry.file, "w")
    vertices = wall.vertices * unit_scale(entry.units, chosen[1] if chosen else "units")
    if entry.mesh is not None:
        vertices = entry.mesh.transform(vertices)
    entry.vertices, entry.faces = vertices, wall.faces
    entry.triangles = vertices[wall.faces]
    check_wall_coordinates(entry.name, vertices, str(entry.file))


def _script_sources(entry: _Entry, script: RunScript | None, dem_dt: float) -> None:
    if script is None or entry.mesh is None:
        return
    found = script.motion_for(entry.mesh.fix_id, dem_dt)
    if found is None:  # the script moves it never (or stops it before it moves)
        source = f"{script.what} (no move/mesh on {entry.mesh.fix_id})"
        entry.motions.append(_Motion(IDENTITY, WallMotion("static"), source, SCRIPT))
    else:
        motion, where = found
        entry.motions.append(_Motion(IDENTITY, motion, f"{script.what} ({where})", SCRIPT))
    mesh = entry.mesh
    if mesh.removed_where is not None:
        if not mesh.removed_known:
            raise InputError(
                f"{mesh.removed_where}: the step of 'unfix {mesh.fix_id}' is unknown "
                f"({script.problems.get('step', 'no step count')}); pass the run's log (--log) "
                "or give removal_time in walls.yaml"
            )
        source = f"{script.what} ({mesh.removed_where})"
        entry.removals.append(_Removal(mesh.removed_step * dem_dt, source, SCRIPT))
    else:
        source = f"{script.what} (no 'unfix {mesh.fix_id}')"
        entry.removals.append(_Removal(math.inf, source, SCRIPT))


def _yaml_sources(entry: _Entry, tau0: float) -> None:
    wall = entry.yaml
    if wall.motion is not None:
        m = wall.motion
        stop = None if m.stop_time is None else m.stop_time + tau0
        motion = replace(m, start_time=m.start_time + tau0, stop_time=stop)
        entry.motions.append(_Motion(IDENTITY, motion, f"{wall.where}.motion", YAML, tau0))
    if wall.removal_time is not None:
        source = f"{wall.where}.removal_time"
        entry.removals.append(_Removal(wall.removal_time + tau0, source, YAML))


# --- resolving -------------------------------------------------------------------------------


def _resolve(entry: _Entry, dem_dt: float, tau0: float, duration: float) -> ImportedWall | None:
    points = entry.triangles.reshape(-1, 3)
    removal, removal_from = _removal(entry, dem_dt, tau0)
    order = sorted(entry.motions, key=lambda m: m.rank)
    chosen = order[0] if order else _Motion(IDENTITY, WallMotion("static"), "static", SCRIPT)
    for other in order[1:]:
        _agree(entry, chosen, other, points, dem_dt, tau0, duration, removal)
    if removal is not None and removal <= tau0:
        return None  # gone before recording started
    vertices = chosen.pose(tau0).apply(entry.vertices)
    motion = _rebase(entry, chosen, tau0, dem_dt)
    removal_time = None if removal is None else _recorded(removal, tau0, dem_dt)
    wall = Wall(entry.name, vertices, entry.faces, motion, removal_time)
    return ImportedWall(wall, entry.file, entry.units, chosen.source, removal_from)


def _removal(entry: _Entry, dem_dt: float, tau0: float) -> tuple[float | None, str | None]:
    """The removal time (absolute, s) and its source, checked across the sources."""
    removals = sorted(entry.removals, key=lambda r: r.rank)
    if not removals:
        return None, None
    chosen = removals[0]

    def when(r: _Removal) -> str:
        if not math.isfinite(r.tau):
            return f"{r.source} never removes it"
        return f"{r.source} removes it at t = {r.tau - tau0:.6g} s"

    for other in removals[1:]:
        if other.rank != MESH_DUMPS and not abs(other.tau - chosen.tau) <= 0.5 * dem_dt:
            raise InputError(
                f"{entry.what}: {when(chosen)}, but {when(other)}; the sources must agree"
            )
    track = entry.track
    if track is not None and track.timesteps and chosen.rank != MESH_DUMPS:
        last = track.timesteps[-1] * dem_dt
        absent = math.inf if track.removed_at is None else track.removed_at * dem_dt
        if not (last - 0.5 * dem_dt <= chosen.tau <= absent + 0.5 * dem_dt):
            gone = (
                f"absent from {track.first_absent_source} (TIMESTEP {track.removed_at})"
                if track.removed_at is not None
                else "present until the last dump"
            )
            raise InputError(
                f"{entry.what}: {when(chosen)}, but the mesh dumps show it in "
                f"{track.sources[-1]} (TIMESTEP {track.timesteps[-1]}) and {gone}; the sources "
                "must agree"
            )
    if not math.isfinite(chosen.tau):
        return None, None
    return chosen.tau, chosen.source


def _agree(
    entry: _Entry,
    chosen: _Motion,
    other: _Motion,
    points: np.ndarray,
    dem_dt: float,
    tau0: float,
    duration: float,
    removal: float | None,
) -> None:
    """Refuse when ``other`` places the wall elsewhere than ``chosen`` at a time both cover:
    every mesh dump for the mesh dumps, else the motions' start and stop times and 11 times
    over the recording."""
    track = entry.track
    allowance = _wiggle_allowance(chosen.motion, dem_dt) + _wiggle_allowance(other.motion, dem_dt)
    if other.rank == MESH_DUMPS and track is not None:
        checks = [
            (ts * dem_dt, pose.apply(points), f"in {src}")
            for ts, pose, src in zip(track.timesteps, track.poses, track.sources, strict=True)
        ]
    else:
        ends = [chosen.motion.start_time, other.motion.start_time]
        ends += [m.stop_time for m in (chosen.motion, other.motion) if m.stop_time is not None]
        span = tau0 + np.linspace(0.0, max(duration, 0.0), 11)
        times = sorted({*span.tolist(), *ends})
        checks = [(t, other.pose(t).apply(points), f"at t = {t - tau0:.6g} s") for t in times]
    lo = max(chosen.valid_from, other.valid_from)
    for tau, target, at in checks:
        if tau < lo - 0.5 * dem_dt or (removal is not None and tau >= removal):
            continue
        deviation = pose_deviation(points, target, chosen.pose(tau))
        tol = dump_tolerance(target) + allowance
        if deviation > tol:
            raise InputError(
                f"{entry.what}: its motion from {chosen.source} misses its pose from "
                f"{other.source} by {deviation:.3g} m (> {tol:.3g} m) {at}; the sources must "
                "agree: fix or drop one of them"
            )


def _wiggle_allowance(motion: WallMotion, dem_dt: float) -> float:
    """LIGGGHTS's ``wiggle`` sums velocity x step: off by up to ``|A| 2 pi / P * dt`` (m)."""
    if motion.kind != "oscillation":
        return 0.0
    return float(np.linalg.norm(motion.amplitude)) * 2 * math.pi / motion.period * dem_dt


def _rebase(entry: _Entry, chosen: _Motion, tau0: float, dem_dt: float) -> WallMotion:
    """``chosen`` in recorded time, for the mesh posed at ``tau0``."""
    m = chosen.motion
    if m.kind == "static":
        return m
    stop = None if m.stop_time is None else _recorded(m.stop_time, tau0, dem_dt)
    if stop is not None and stop <= 0:
        return WallMotion("static")
    start = _recorded(m.start_time, tau0, dem_dt)
    if m.kind == "oscillation" and start < 0:
        cycles = -start / m.period
        if abs(cycles - round(cycles)) > 1e-9:
            raise InputError(
                f"{entry.what}: its oscillation ({chosen.source}) started {-start:.6g} s before "
                "the first dump frame, not a whole number of periods: a WallMotion starts its "
                "sine at its start time; record from a start of the wiggle"
            )
    return replace(m, start_time=max(0.0, start), stop_time=stop)


def _recorded(tau: float, tau0: float, dem_dt: float) -> float:
    """Recorded time ``tau - tau0`` (s), snapped to a whole number of DEM steps when within
    round-off of one."""
    t = tau - tau0
    steps = t / dem_dt
    return round(steps) * dem_dt if abs(steps - round(steps)) < 1e-6 else t


def _identifier(stem: str) -> str:
    name = re.sub(r"[^0-9A-Za-z_]", "_", stem)
    return name if name and not name[0].isdigit() else f"wall_{name}"


def _unique(name: str, taken: set[str]) -> str:
    candidate, k = name, 2
    while candidate in taken:
        candidate, k = f"{name}_{k}", k + 1
    return candidate
