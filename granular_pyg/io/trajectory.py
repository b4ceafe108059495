"""The Trajectory and its HDF5 file format, the project's one on-disk format for simulations.

A :class:`Trajectory` is what any simulator produces (LIGGGHTS ground truth and learned
rollouts alike): particle positions and velocities per recorded frame, radii, LIGGGHTS atom ids,
recorded times, the :class:`~granular_pyg.scenes.Scene` (walls and their motion, so the walls of
every frame follow) and JSON-able metadata.

File layout (``format = "granular_pyg.trajectory"``, ``format_version = 1``), one HDF5 file,
``T`` frames, ``N`` particles::

    /                      attrs: format      = "granular_pyg.trajectory"
                                  format_version = 1
                                  metadata    = JSON string (seed, liggghts_version, params, ...)
    /positions             [T, N, 3] float32 (m); NaN from the first frame a particle has left
    /velocities            [T, N, 3] float32 (m/s); NaN likewise
                           both chunked by up to 16 frames, shuffle + gzip (level 4 default)
    /radii                 [N] float32 (m)
    /ids                   [N] int64, strictly ascending (LIGGGHTS atom ids)
    /times                 [T] float64 (s), recorded time (strictly increasing, usually from 0)
    /scene                 only when the trajectory has a Scene
                           attrs: json = JSON of Scene.to_dict() with every wall's "vertices"
                                         and "faces" removed
    /scene/walls/<name>/vertices   [V, 3] float64 (m), mesh frame
    /scene/walls/<name>/faces      [F, 3] int64

The round trip is exact: arrays come back bit for bit (NaNs included), the Scene's dict and the
metadata compare equal (metadata must hold JSON types: dicts with string keys, lists, strings,
numbers, booleans, None). Writes are atomic: the file is written under a temporary name in the
destination folder and renamed onto ``path`` only when complete, so a reader sees the old file or
the new one, never a partial one.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from granular_pyg.errors import InputError
from granular_pyg.io.atomic import atomic_path
from granular_pyg.scenes.scene import Scene

__all__ = ["FORMAT", "FORMAT_VERSION", "Trajectory", "read_trajectory", "write_trajectory"]

FORMAT = "granular_pyg.trajectory"
FORMAT_VERSION = 1
_DATASETS = ("positions", "velocities", "radii", "ids", "times")
_CHUNK_FRAMES = 16


@dataclass
class Trajectory:
    """Particle states over recorded frames, with the scene they moved in.

    Attributes:
        positions: ``[T, N, 3]`` float32 (m); NaN from the first frame a particle has left.
        velocities: ``[T, N, 3]`` float32 (m/s); NaN likewise.
        radii: ``[N]`` float32 (m).
        ids: ``[N]`` int64, strictly ascending (LIGGGHTS atom ids).
        times: ``[T]`` float64 (s), strictly increasing recorded times; the first is usually 0.
        scene: the walls and their motion (so the walls at every frame), or None.
        metadata: JSON-able facts about the run (seed, liggghts_version, params, ...).

    Inputs are cast to the dtypes above; inconsistent shapes, unsorted ids or non-increasing
    times raise :class:`~granular_pyg.errors.InputError` naming the field.
    """

    positions: np.ndarray
    velocities: np.ndarray
    radii: np.ndarray
    ids: np.ndarray
    times: np.ndarray
    scene: Scene | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions = _as_array("positions", self.positions, np.float32, 3)
        self.velocities = _as_array("velocities", self.velocities, np.float32, 3)
        self.radii = _as_array("radii", self.radii, np.float32, 1)
        self.ids = _as_ids(self.ids)
        self.times = _as_array("times", self.times, np.float64, 1)

        num_frames, num_particles = self.positions.shape[:2]
        if self.positions.shape[2] != 3:
            raise InputError(f"positions: expected shape [T, N, 3], got {self.positions.shape}")
        if num_frames == 0:
            raise InputError("positions: a trajectory needs at least one frame, got T = 0")
        if self.velocities.shape != self.positions.shape:
            raise InputError(
                f"velocities: expected the shape of positions {list(self.positions.shape)}, "
                f"got {list(self.velocities.shape)}"
            )
        for name, value, size, what in (
            ("radii", self.radii, num_particles, "N"),
            ("ids", self.ids, num_particles, "N"),
            ("times", self.times, num_frames, "T"),
        ):
            if len(value) != size:
                raise InputError(
                    f"{name}: expected shape [{what}] = [{size}] to match positions "
                    f"{list(self.positions.shape)}, got {list(value.shape)}"
                )
        if num_particles > 1 and not np.all(np.diff(self.ids) > 0):
            first = int(np.flatnonzero(np.diff(self.ids) <= 0)[0])
            raise InputError(
                f"ids: must be strictly ascending, but ids[{first}] = {self.ids[first]} is "
                f"followed by {self.ids[first + 1]}; sort the particles by id (drop duplicates)"
            )
        if not np.isfinite(self.times).all():
            raise InputError("times: contain NaN or Inf; give every frame a finite time (s)")
        if num_frames > 1 and not np.all(np.diff(self.times) > 0):
            first = int(np.flatnonzero(np.diff(self.times) <= 0)[0])
            raise InputError(
                f"times: must be strictly increasing, but times[{first}] = {self.times[first]} "
                f"is followed by {self.times[first + 1]}; sort or deduplicate the frames"
            )
        if not (np.isfinite(self.radii).all() and np.all(self.radii > 0)):
            raise InputError("radii: every radius must be finite and positive (m)")
        if self.scene is not None and not isinstance(self.scene, Scene):
            raise InputError(
                f"scene: expected a granular_pyg.scenes.Scene or None, got {type(self.scene)}"
            )
        if not isinstance(self.metadata, dict):
            raise InputError(f"metadata: expected a dict, got {type(self.metadata).__name__}")

    def check_even_spacing(self, tolerance: float = 1e-6) -> None:
        """Refuse frames that are not evenly spaced (a dropped or duplicated frame): learned
        steps and initial velocities assume one spacing.

        Raises:
            InputError: naming the first uneven frame, its time and the spacing.
        """
        if self.num_frames < 3:
            return
        gaps = np.diff(self.times)
        spacing = float(np.median(gaps))
        bad = np.flatnonzero(np.abs(gaps - spacing) > tolerance * spacing)
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"times: frames are not evenly spaced: frame {i + 1} (t = {self.times[i + 1]:.6g} "
                f"s) follows frame {i} after {gaps[i]:.6g} s, not the {spacing:.6g} s of the "
                f"others ({bad.size} uneven gap(s)); a frame was dropped or duplicated: convert "
                "the run again (dem.convert refuses gaps) or cut the trajectory there"
            )

    @property
    def num_frames(self) -> int:
        """Number of recorded frames ``T``."""
        return int(self.positions.shape[0])

    @property
    def num_particles(self) -> int:
        """Number of particles ``N`` (every particle that was ever present)."""
        return int(self.positions.shape[1])

    @property
    def frame_dt(self) -> float:
        """Median spacing of ``times`` (s).

        With a single frame, the scene's ``frame_dt`` if there is a scene, else NaN.
        """
        if self.num_frames < 2:
            return float(self.scene.frame_dt) if self.scene is not None else float("nan")
        return float(np.median(np.diff(self.times)))

    @property
    def present(self) -> np.ndarray:
        """``[T, N]`` bool: whether the particle is in the scene (finite position) in the frame."""
        return np.isfinite(self.positions).all(axis=2)

    def wall_vertices(self, name: str, frame: int) -> np.ndarray:
        """World-frame vertices of wall ``name`` at recorded frame ``frame``.

        Args:
            name: the wall's name in the scene.
            frame: frame index (negative counts from the end).

        Returns:
            ``[V, 3]`` float64 (m), ``scene.wall(name).vertices_at(times[frame])``.
        """
        if self.scene is None:
            raise InputError("wall_vertices: this trajectory has no scene; attach one first")
        if not -self.num_frames <= frame < self.num_frames:
            raise InputError(f"frame: expected an index in [0, {self.num_frames}), got {frame}")
        return self.scene.wall(name).vertices_at(float(self.times[frame]))


def write_trajectory(
    traj: Trajectory,
    path: str | os.PathLike,
    compression: str | None = "gzip",
    level: int = 4,
) -> None:
    """Write ``traj`` to one HDF5 file at ``path``, atomically (see the module docstring).

    Args:
        traj: the trajectory.
        path: destination file (conventionally ``*.h5``); its folder is created if missing and an
            existing file is replaced only once the new one is complete.
        compression: ``"gzip"`` (with ``level``), ``"lzf"``, or None for no compression of
            ``positions`` and ``velocities``; compression is lossless either way.
        level: gzip level 0-9.

    Raises:
        InputError: ``traj`` is not a Trajectory, the metadata or scene is not JSON-able, or the
            compression settings are unknown.
    """
    if not isinstance(traj, Trajectory):
        raise InputError(f"traj: expected a Trajectory, got {type(traj).__name__}")
    if compression not in ("gzip", "lzf", None):
        raise InputError(f"compression: expected 'gzip', 'lzf' or None, got {compression!r}")
    if compression == "gzip" and not (isinstance(level, int) and 0 <= level <= 9):
        raise InputError(f"level: gzip level must be an integer in 0..9, got {level!r}")
    metadata_json = _to_json("metadata", traj.metadata)
    scene_json = None
    if traj.scene is not None:
        scene_dict = traj.scene.to_dict()
        for wall in scene_dict["walls"]:
            del wall["vertices"], wall["faces"]
        scene_json = _to_json("scene", scene_dict)

    with atomic_path(path) as tmp, h5py.File(tmp, "w") as h5:
        h5.attrs["format"] = FORMAT
        h5.attrs["format_version"] = FORMAT_VERSION
        h5.attrs["metadata"] = metadata_json
        _write_arrays(h5, traj, compression, level)
        if traj.scene is not None:
            _write_scene(h5, traj.scene, scene_json)


def read_trajectory(path: str | os.PathLike) -> Trajectory:
    """Read a trajectory written by :func:`write_trajectory`.

    Args:
        path: the HDF5 file.

    Returns:
        The Trajectory, bit for bit as written.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        InputError: the file is not HDF5, is truncated or corrupt, is not a granular_pyg
            trajectory (wrong ``format``), is from a newer format version, lacks a dataset, or
            holds inconsistent shapes; the message names the path and what to do.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no such trajectory file; check the path (write one with write_trajectory "
            "or python -m granular_pyg.dem_import.convert)"
        )
    try:
        with h5py.File(path, "r") as h5:
            return _read_open(h5, path)
    except (OSError, RuntimeError, KeyError) as err:
        raise InputError(
            f"{path}: cannot read the HDF5 file ({err}); it is corrupt or truncated (an "
            "interrupted copy?): regenerate it or copy it again"
        ) from err


def _read_open(h5: h5py.File, path: Path) -> Trajectory:
    fmt = h5.attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode()
    if fmt != FORMAT:
        raise InputError(
            f"{path}: not a granular_pyg trajectory (root attribute format = {fmt!r}, expected "
            f"{FORMAT!r}); pass a file written by write_trajectory"
        )
    version = int(h5.attrs.get("format_version", -1))
    if version != FORMAT_VERSION:
        raise InputError(
            f"{path}: trajectory format_version {version} is not supported (this granular_pyg "
            f"reads version {FORMAT_VERSION}); use the granular_pyg version that wrote it"
        )
    arrays = {}
    for name in _DATASETS:
        if not isinstance(h5.get(name), h5py.Dataset):
            raise InputError(
                f"{path}: dataset '/{name}' is missing; the file is incomplete, regenerate it"
            )
        arrays[name] = h5[name][()]
    metadata = _from_json(path, "metadata", h5.attrs.get("metadata", "{}"))
    scene = _read_scene(h5, path) if "scene" in h5 else None
    try:
        return Trajectory(**arrays, scene=scene, metadata=metadata)
    except InputError as err:
        raise InputError(f"{path}: {err}; the file is inconsistent, regenerate it") from err


def _write_arrays(h5: h5py.File, traj: Trajectory, compression: str | None, level: int) -> None:
    num_particles = traj.num_particles
    options: dict[str, Any] = {}
    if num_particles > 0:
        # Chunks of up to 16 frames: gzip then sees each particle's slow drift over time.
        options["chunks"] = (max(1, min(traj.num_frames, _CHUNK_FRAMES)), num_particles, 3)
        if compression is not None:
            options["shuffle"] = True
            options["compression"] = compression
            if compression == "gzip":
                options["compression_opts"] = level
    h5.create_dataset("positions", data=traj.positions, **options)
    h5.create_dataset("velocities", data=traj.velocities, **options)
    h5.create_dataset("radii", data=traj.radii)
    h5.create_dataset("ids", data=traj.ids)
    h5.create_dataset("times", data=traj.times)


def _write_scene(h5: h5py.File, scene: Scene, scene_json: str) -> None:
    group = h5.create_group("scene")
    group.attrs["json"] = scene_json
    walls = group.create_group("walls")
    for wall in scene.walls:
        wall_group = walls.create_group(wall.name)
        wall_group.create_dataset("vertices", data=np.asarray(wall.vertices, np.float64))
        wall_group.create_dataset("faces", data=np.asarray(wall.faces, np.int64))


def _read_scene(h5: h5py.File, path: Path) -> Scene:
    group = h5["scene"]
    if "json" not in group.attrs:
        raise InputError(f"{path}: group '/scene' lacks its 'json' attribute; regenerate the file")
    data = _from_json(path, "scene", group.attrs["json"])
    try:
        for wall in data["walls"]:
            for key in ("vertices", "faces"):
                name = f"scene/walls/{wall['name']}/{key}"
                if not isinstance(h5.get(name), h5py.Dataset):
                    raise InputError(
                        f"{path}: dataset '/{name}' is missing; the file is incomplete, "
                        "regenerate it"
                    )
                wall[key] = h5[name][()]
        return Scene.from_dict(data)
    except (KeyError, TypeError) as err:
        raise InputError(
            f"{path}: the scene in '/scene' is malformed ({err!r}); regenerate the file"
        ) from err
    except InputError as err:
        raise InputError(f"{path}: {err}") from err


def _to_json(name: str, value: Any) -> str:
    try:
        return json.dumps(value)
    except (TypeError, ValueError) as err:
        raise InputError(
            f"{name}: not JSON-able ({err}); use dicts with string keys, lists, strings, "
            "numbers, booleans and None (convert numpy values with .item() or .tolist())"
        ) from err


def _from_json(path: Path, name: str, text: Any) -> Any:
    if isinstance(text, bytes):
        text = text.decode()
    try:
        return json.loads(text)
    except (TypeError, ValueError) as err:
        raise InputError(
            f"{path}: the {name} attribute is not valid JSON ({err}); regenerate the file"
        ) from err


def _as_array(name: str, value: Any, dtype: type, ndim: int) -> np.ndarray:
    try:
        array = np.ascontiguousarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name}: cannot convert to {np.dtype(dtype).name} ({err})") from err
    if array.ndim != ndim:
        dims = {1: "[T]" if name == "times" else "[N]", 3: "[T, N, 3]"}[ndim]
        raise InputError(f"{name}: expected shape {dims}, got {list(array.shape)}")
    return array


def _as_ids(value: Any) -> np.ndarray:
    raw = np.asarray(value)
    if raw.dtype.kind == "f" and not np.all(np.isfinite(raw) & (raw == np.round(raw))):
        raise InputError("ids: must be whole numbers (LIGGGHTS atom ids)")
    if raw.dtype.kind not in "iuf" and raw.size:
        raise InputError(f"ids: expected integers, got dtype {raw.dtype}")
    return _as_array("ids", raw, np.int64, 1)
