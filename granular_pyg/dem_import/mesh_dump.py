"""LIGGGHTS mesh dumps: which wall is where at every dump step, and the motion that moved it.

``dump dmesh all mesh/stl 125 post/mesh*.stl`` (or ``mesh/vtk ... post/mesh*.vtk``) writes one
file per dump step, named with its TIMESTEP (the ``*``), holding the triangles of every mesh in
the order their ``fix mesh/surface`` commands were given (or of the meshes listed after the file
name), all merged into one solid (measured with LIGGGHTS 3.8.0). Coordinates are written with 6
significant digits.

:func:`read_mesh_dumps` reads those files; :func:`track_walls` splits each file's triangles into
the known meshes (consecutive blocks matched by triangle count and order, each checked to be a
rigid copy of its reference mesh), fits every wall's pose per step (Kabsch) and notes the step a
wall stops appearing: its removal (LIGGGHTS cannot unfix a mesh while a mesh dump is active, so
a removal always re-creates the dump, whose first file lacks the mesh). :func:`motion_from_track`
turns a wall's poses into one :class:`~granular_pyg.scenes.WallMotion`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from granular_pyg.dem_import.rigid_fit import (
    MotionFitError,
    Pose,
    dump_tolerance,
    fit_motion,
    fit_pose,
    pose_deviation,
)
from granular_pyg.dem_import.stitch import dump_files
from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import WallMotion

__all__ = [
    "MeshFrame",
    "MeshRef",
    "WallTrack",
    "motion_from_track",
    "read_mesh_dumps",
    "track_walls",
]

MESH_SUFFIXES = (".stl", ".vtk")
_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")
_STEP = re.compile(r"(\d+)(?!.*\d)")


@dataclass
class MeshFrame:
    """One mesh dump file.

    Attributes:
        timestep: the DEM step it was written at (from the file name).
        triangles: ``[F, 3, 3]`` float64 corner positions (m), in file order.
        source: the file.
    """

    timestep: int
    triangles: np.ndarray
    source: Path


@dataclass
class MeshRef:
    """A mesh LIGGGHTS knows, as loaded (before any motion).

    Attributes:
        name: the wall's name.
        triangles: ``[F, 3, 3]`` float64 corners (m), in the order LIGGGHTS keeps them (the STL
            file's).
        is_wall: False for a mesh that is no wall (e.g. an insertion face) but is in the dumps.
    """

    name: str
    triangles: np.ndarray
    is_wall: bool = True


@dataclass
class WallTrack:
    """Where the mesh dumps show one mesh.

    Attributes:
        name: the mesh's name.
        timesteps: ``[K]`` dump steps at which it is present, increasing.
        poses: ``K`` poses mapping its reference (as loaded) onto the dumped triangles.
        sources: ``K`` files.
        removed_at: the first dump step after its last appearance at which it is absent (its
            removal), or None.
        first_absent_source: the file of that step, for messages.
    """

    name: str
    timesteps: list[int] = field(default_factory=list)
    poses: list[Pose] = field(default_factory=list)
    sources: list[Path] = field(default_factory=list)
    removed_at: int | None = None
    first_absent_source: Path | None = None


def read_mesh_dumps(paths: Sequence[str | os.PathLike], pattern: str = "*") -> list[MeshFrame]:
    """Read ``dump mesh/stl`` (ASCII or binary STL) and ``dump mesh/vtk`` (ASCII legacy VTK)
    files.

    Args:
        paths: mesh dump files and/or folders; in a folder, the files whose names match
            ``pattern`` and end in ``.stl`` or ``.vtk``.
        pattern: glob for file names in folders.

    Returns:
        The frames sorted by TIMESTEP; a step written twice (an old dump's last file and a
        re-created dump's first, or as .stl and .vtk) is kept once if the same within
        :func:`~granular_pyg.dem_import.rigid_fit.dump_tolerance`, else both are kept, the one with
        more triangles first.

    Raises:
        FileNotFoundError: a path does not exist.
        InputError: a file name without its TIMESTEP, an unreadable file, or no file at all.
    """
    files = dump_files(paths, pattern, MESH_SUFFIXES, "mesh dump", "--mesh-pattern")
    frames = []
    for path in files:
        match = _STEP.search(path.stem)
        if match is None:
            raise InputError(
                f"{path}: no TIMESTEP in the file name; write mesh dumps one file per step, "
                "e.g. 'dump dmesh all mesh/stl 125 post/mesh*.stl'"
            )
        triangles = _read_vtk(path) if path.suffix.lower() == ".vtk" else _read_stl(path)
        frames.append(MeshFrame(int(match.group(1)), triangles, path))
    frames.sort(key=lambda f: (f.timestep, -len(f.triangles)))
    unique: list[MeshFrame] = []
    for frame in frames:
        last = unique[-1] if unique else None
        if (
            last is not None
            and last.timestep == frame.timestep
            and last.triangles.shape == frame.triangles.shape
            and np.abs(last.triangles - frame.triangles).max(initial=0.0)
            <= dump_tolerance(frame.triangles)
        ):
            continue  # the same step written twice (e.g. as .stl and .vtk)
        unique.append(frame)
    return unique


def track_walls(frames: Sequence[MeshFrame], meshes: Sequence[MeshRef]) -> dict[str, WallTrack]:
    """Split every mesh dump into ``meshes`` and fit each one's pose.

    A file's triangles are consecutive blocks, one per mesh present, in the order of
    ``meshes`` (other orders are tried when that fails); a block belongs to a mesh when it has
    the mesh's triangle count and is a rigid copy of it within :func:`dump_tolerance`.

    Returns:
        One :class:`WallTrack` per mesh (including meshes never seen: empty tracks).

    Raises:
        InputError: a file that no combination of the meshes explains (naming the file, its
            triangle count, the meshes' counts, and the mesh whose shape does not match when
            the counts fit), a mesh that reappears after it was gone, or a wall that appears
            only after the first dump.
    """
    tracks = {m.name: WallTrack(m.name) for m in meshes}
    refs = [m.triangles.reshape(-1, 3) for m in meshes]
    counts = [len(m.triangles) for m in meshes]
    previous: list[int] = list(range(len(meshes)))
    for frame in frames:
        points = frame.triangles.reshape(-1, 3)
        tol = dump_tolerance(points)
        found = _split(points, refs, counts, previous, tol, check=True)
        if found is None:
            _explain_split_failure(frame, meshes, refs, counts, previous, tol)
        previous = [k for k, _ in found]
        present = set(previous)
        for k, pose in found:
            track = tracks[meshes[k].name]
            if track.timesteps and track.timesteps[-1] == frame.timestep:
                continue  # a step written twice, before and after a removal
            if track.removed_at is not None:
                raise InputError(
                    f"mesh dumps: mesh {meshes[k].name} is absent from {track.first_absent_source}"
                    f" (TIMESTEP {track.removed_at}) but back in {frame.source} (TIMESTEP "
                    f"{frame.timestep}); a removed wall cannot come back: check the dump files"
                )
            track.timesteps.append(frame.timestep)
            track.poses.append(pose)
            track.sources.append(frame.source)
        for k, mesh in enumerate(meshes):
            track = tracks[mesh.name]
            if k not in present and track.timesteps and track.removed_at is None:
                track.removed_at, track.first_absent_source = frame.timestep, frame.source
    if frames:
        first = frames[0].timestep
        for mesh in meshes:
            track = tracks[mesh.name]
            if mesh.is_wall and track.timesteps and track.timesteps[0] != first:
                raise InputError(
                    f"mesh dumps: wall {mesh.name} first appears in {track.sources[0]} (TIMESTEP "
                    f"{track.timesteps[0]}), not in the first dump {frames[0].source}; walls "
                    "added during the run are not supported"
                )
    return tracks


def motion_from_track(
    track: WallTrack, reference: np.ndarray, dem_dt: float
) -> tuple[Pose, WallMotion]:
    """The constant motion behind a wall's dumped poses.

    Args:
        track: the wall's poses (at least one).
        reference: ``[P, 3]`` its points as loaded (m).
        dem_dt: DEM time step (s); times are ``TIMESTEP * dem_dt``.

    Returns:
        ``(base, motion)``: ``base`` is the pose at the track's first dump (relative to the
        reference) and ``motion`` (times ``TIMESTEP * dem_dt``) moves the based mesh, so that
        the pose at time ``tau`` is ``base`` then ``motion.pose(tau)``.

    Raises:
        InputError: no single rotation or translation fits, naming the wall and the dumps.
    """
    base = track.poses[0]
    based = base.apply(reference)
    relative = [base.inverse().then(p) for p in track.poses]
    times = np.asarray(track.timesteps, np.float64) * dem_dt
    tol = max(dump_tolerance(p.apply(reference)) for p in track.poses)
    try:
        motion = fit_motion(times, relative, based, tol, dem_dt)
    except MotionFitError as err:
        raise InputError(
            f"wall {track.name}: in the mesh dumps {track.sources[0]} .. {track.sources[-1]} "
            f"{err}; give its motion in walls.yaml (motion:) or with --input"
        ) from None
    return base, motion


# --- splitting -------------------------------------------------------------------------------


def _split(
    points: np.ndarray,
    refs: list[np.ndarray],
    counts: list[int],
    previous: list[int],
    tol: float,
    check: bool,
) -> list[tuple[int, Pose]] | None:
    """Blocks of ``points`` as ``[(mesh index, pose)]`` in file order, or None.

    Depth-first over the meshes, trying first the order of the previous file, then the meshes'
    order; with ``check`` a block must be a rigid copy of its mesh within ``tol``.
    """
    total = len(points) // 3
    order = previous + [k for k in range(len(refs)) if k not in previous]

    def search(offset: int, used: list[int]) -> list[tuple[int, Pose]] | None:
        if offset == total:
            return []
        after = [k for k in order if k not in used]
        if used:  # keep going in order after the last placed mesh
            tail = [k for k in order[order.index(used[-1]) + 1 :] if k not in used]
            after = tail + [k for k in after if k not in tail]
        for k in after:
            n = counts[k]
            if offset + n > total:
                continue
            block = points[3 * offset : 3 * (offset + n)]
            pose = fit_pose(refs[k], block)
            if check and pose_deviation(refs[k], block, pose) > tol:
                continue
            rest = search(offset + n, [*used, k])
            if rest is not None:
                return [(k, pose), *rest]
        return None

    return search(0, [])


def _explain_split_failure(
    frame: MeshFrame,
    meshes: Sequence[MeshRef],
    refs: list[np.ndarray],
    counts: list[int],
    previous: list[int],
    tol: float,
) -> None:
    """Raise the InputError that says why ``frame`` matches no combination of ``meshes``."""
    points = frame.triangles.reshape(-1, 3)
    by_count = _split(points, refs, counts, previous, tol, check=False)
    listed = ", ".join(f"{m.name}: {len(m.triangles)}" for m in meshes)
    if by_count is None:
        raise InputError(
            f"{frame.source}: holds {len(frame.triangles)} triangles, which no combination of "
            f"the meshes ({listed} triangles) adds up to; pass every mesh the dump holds (--stl "
            "or --input) or dump only the walls ('dump ... mesh/stl N file* <mesh ids>')"
        )
    offset = 0
    for k, pose in by_count:
        n = counts[k]
        block = points[3 * offset : 3 * (offset + n)]
        deviation = pose_deviation(refs[k], block, pose)
        if deviation > tol:
            raise InputError(
                f"wall {meshes[k].name}: in {frame.source} (TIMESTEP {frame.timestep}) its "
                f"{n} triangles are no rigid copy of its mesh: they miss by {deviation:.3g} m "
                f"(> {tol:.3g} m); check the STL file, its units (--units), and that the mesh "
                "does not deform"
            )
        offset += n
    raise InputError(f"{frame.source}: cannot split the mesh dump into {listed}")  # unreachable


# --- file formats ----------------------------------------------------------------------------


def _read_stl(path: Path) -> np.ndarray:
    """``[F, 3, 3]`` triangles of an ASCII or binary STL file (all solids in it); a file is
    binary when its size is exactly that of the triangle count in its header."""
    raw = path.read_bytes()
    if len(raw) >= 84:
        count = int(np.frombuffer(raw, "<u4", 1, 80)[0])
        if len(raw) == 84 + 50 * count:
            record = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
            return np.frombuffer(raw, record, count, 84)["v"].astype(np.float64)
    if raw.strip() and raw.lstrip()[:5].lower() != b"solid":
        raise InputError(
            f"{path}: neither an ASCII nor a binary STL file; the mesh dump is corrupt"
        )
    values = _VERTEX.findall(raw)
    if len(values) % 3:
        raise InputError(
            f"{path}: {len(values)} vertex lines, not a multiple of 3; the mesh dump is "
            "truncated or corrupt, regenerate it"
        )
    try:
        corners = np.array(values, dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: a vertex holds a non-number; the file is corrupt") from None
    return corners.reshape(-1, 3, 3)


def _read_vtk(path: Path) -> np.ndarray:
    """``[F, 3, 3]`` triangles of an ASCII legacy VTK polydata file (``POINTS`` and
    ``POLYGONS``, the 5.1 ``OFFSETS``/``CONNECTIVITY`` layout or the older ``n i j k`` one)."""
    tokens = path.read_bytes().split()
    try:
        if b"BINARY" in tokens[:8]:
            raise InputError(f"{path}: binary VTK is not supported; dump the meshes as ASCII")
        k = tokens.index(b"POINTS")
        n = int(tokens[k + 1])
        points = np.array(tokens[k + 3 : k + 3 + 3 * n], dtype=np.float64).reshape(n, 3)
        k = tokens.index(b"POLYGONS")
        cells = int(tokens[k + 1])
        if tokens[k + 3] == b"OFFSETS":
            offsets = np.array(tokens[k + 5 : k + 5 + cells], dtype=np.int64)
            c = tokens.index(b"CONNECTIVITY", k)
            conn = np.array(tokens[c + 2 : c + 2 + offsets[-1]], dtype=np.int64)
            sizes = np.diff(offsets)
        else:
            size = int(tokens[k + 2])
            flat = np.array(tokens[k + 3 : k + 3 + size], dtype=np.int64)
            sizes, conn, i = [], [], 0
            while i < len(flat):
                sizes.append(int(flat[i]))
                conn.extend(flat[i + 1 : i + 1 + flat[i]])
                i += 1 + int(flat[i])
            sizes, conn = np.array(sizes), np.array(conn, np.int64)
    except (ValueError, IndexError):
        raise InputError(
            f"{path}: not a readable ASCII VTK polydata mesh dump (POINTS/POLYGONS); "
            "regenerate it or dump the meshes as STL (dump ... mesh/stl)"
        ) from None
    if len(sizes) and not np.all(sizes == 3):
        raise InputError(f"{path}: polygons with other than 3 corners; expected triangles")
    return points[conn.reshape(-1, 3)]
