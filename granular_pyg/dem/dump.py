"""Parser for LIGGGHTS/LAMMPS ``dump custom`` text files.

One frame looks like::

    ITEM: TIMESTEP
    1000
    ITEM: NUMBER OF ATOMS
    3
    ITEM: BOX BOUNDS ff ff ff
    -0.05 0.05
    -0.02 0.02
    -0.01 0.2
    ITEM: ATOMS id type x y z vx vy vz radius
    3 1 0.01 0.0 0.05 0 0 -0.1 0.0015
    ...

A file holds one or many frames; a run may also write one file per frame (``dump ... post/
dump*.liggghts``), read here as a folder. Atom lines may come in any order and a frame may hold
fewer atoms than earlier ones (atoms deleted at the outflow). CRLF line ends and blank lines are
accepted; other ``ITEM:`` sections (``UNITS``, ``TIME``, ...) are skipped.

Speed: the file is read whole, the ``ITEM:`` headers are located with ``bytes.find`` and each
frame's atom block is converted in one call to numpy's C parser (``np.loadtxt``); Python only
looks at individual lines to explain an error. About 1 s for 2,000 atoms x 400 frames (800k atom
lines) on the 2-core reference machine.

Truncation: a run that is killed mid-write leaves its last frame incomplete (too few atom lines,
a cut line, or a header without its atoms). That frame is dropped with a warning
(``on_truncated="warn"``) or raises (``"raise"``); any other malformed content raises
:class:`~granular_pyg.errors.InputError` naming the file and line.
"""

from __future__ import annotations

import io
import itertools
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from granular_pyg.errors import InputError

__all__ = ["REQUIRED_COLUMNS", "DumpFrame", "frames_to_arrays", "read_dump"]

REQUIRED_COLUMNS = ("id", "x", "y", "z", "vx", "vy", "vz", "radius")
_HEADER_ORDER = ("TIMESTEP", "NUMBER OF ATOMS", "BOX BOUNDS", "ATOMS")
_DUMP_HINT = "dump d all custom <N> <file> id type x y z vx vy vz radius"


@dataclass
class DumpFrame:
    """One frame of a ``dump custom`` file.

    Attributes:
        timestep: the DEM step number (``ITEM: TIMESTEP``).
        box: ``[3, 2]`` float64 box bounds (m), rows x, y, z and columns lo, hi.
        columns: names from the ``ITEM: ATOMS`` line, e.g. ``["id", "type", "x", ...]``.
        data: ``[n, len(columns)]`` float64 atom values, in file order.
        source: the file the frame came from (for error messages).
        line: 1-based line of the frame's ``ITEM: TIMESTEP`` in ``source``.
    """

    timestep: int
    box: np.ndarray
    columns: list[str]
    data: np.ndarray
    source: str = ""
    line: int = 0

    @property
    def num_atoms(self) -> int:
        """Number of atom lines ``n`` in the frame."""
        return int(self.data.shape[0])

    def column(self, name: str) -> np.ndarray:
        """``[n]`` float64 values of column ``name``.

        Raises:
            InputError: the frame has no such column (the message lists the columns it has).
        """
        try:
            return self.data[:, self.columns.index(name)]
        except ValueError:
            raise InputError(
                f"{self.where}: no column {name!r} in 'ITEM: ATOMS {' '.join(self.columns)}'; "
                f"write it in the dump, e.g. '{_DUMP_HINT}'"
            ) from None

    @property
    def where(self) -> str:
        """``"file:line (TIMESTEP t)"`` for messages."""
        return f"{self.source}:{self.line} (TIMESTEP {self.timestep})"


def read_dump(
    path: str | os.PathLike,
    on_truncated: str = "warn",
    pattern: str = "*",
) -> list[DumpFrame]:
    """Read every frame of a dump file, or of a folder of dump files.

    Args:
        path: a dump file (one or many frames) or a folder; in a folder every regular file whose
            name matches ``pattern`` is read and the files are ordered by their first TIMESTEP.
        on_truncated: what to do with a truncated last frame of a file: ``"warn"`` drops it with
            a warning naming the file and line, ``"raise"`` raises InputError.
        pattern: glob for file names in a folder, e.g. ``"dump*.liggghts"``.

    Returns:
        The frames in file order (files ordered by first TIMESTEP).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        InputError: malformed content (non-numeric value, wrong column count, missing ``id``
            column, ...), a truncated frame with ``on_truncated="raise"``, or no frames at all;
            the message names the file and line.
    """
    if on_truncated not in ("warn", "raise"):
        raise InputError(f"on_truncated: expected 'warn' or 'raise', got {on_truncated!r}")
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.glob(pattern) if p.is_file())
        if not files:
            raise InputError(
                f"{path}: no files match {pattern!r} in this folder; check the folder or pattern"
            )
        per_file = [_read_file(p, on_truncated) for p in files]
        per_file = [frames for frames in per_file if frames]
        per_file.sort(key=lambda frames: frames[0].timestep)
        frames = [frame for frames in per_file for frame in frames]
    elif path.is_file():
        frames = _read_file(path, on_truncated)
    else:
        raise FileNotFoundError(f"{path}: no such dump file or folder; check the path")
    if not frames:
        raise InputError(f"{path}: no complete dump frame found; check that it is a LIGGGHTS dump")
    return frames


def frames_to_arrays(frames: list[DumpFrame], dem_dt: float) -> dict[str, Any]:
    """Stack frames into trajectory arrays, one slot per atom id ever seen.

    Args:
        frames: frames with strictly increasing timesteps and the columns ``id x y z vx vy vz
            radius`` (others are ignored).
        dem_dt: DEM time step (s), to turn timesteps into times.

    Returns:
        A dict with ``positions`` ``[T, N, 3]`` float32 (m) and ``velocities`` ``[T, N, 3]``
        float32 (m/s), NaN where an atom is absent from a frame; ``radii`` ``[N]`` float32 (m)
        from each atom's first appearance; ``ids`` ``[N]`` int64, the sorted union of ids;
        ``times`` ``[T]`` float64 (s), ``(timestep - first_timestep) * dem_dt``; and
        ``first_timestep`` (int).

    Raises:
        InputError: no frames, a bad ``dem_dt``, a missing column, non-integer or duplicate ids
            in a frame, or timesteps that do not increase.
    """
    if not frames:
        raise InputError("frames: empty; read_dump found no frames to convert")
    if not (isinstance(dem_dt, (int, float)) and np.isfinite(dem_dt) and dem_dt > 0):
        raise InputError(f"dem_dt: expected a positive DEM time step in seconds, got {dem_dt!r}")
    for prev, frame in itertools.pairwise(frames):
        if frame.timestep <= prev.timestep:
            raise InputError(
                f"{frame.where}: TIMESTEP {frame.timestep} does not follow {prev.where}; frames "
                "must have strictly increasing timesteps (remove duplicated or stray dump files)"
            )
    frame_ids = []
    for frame in frames:
        missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
        if missing:
            raise InputError(
                f"{frame.where}: missing column(s) {missing} in "
                f"'ITEM: ATOMS {' '.join(frame.columns)}'; write them in the dump, e.g. "
                f"'{_DUMP_HINT}'"
            )
        raw = frame.column("id")
        if not np.all(np.isfinite(raw) & (raw == np.round(raw))):
            raise InputError(f"{frame.where}: column 'id' holds non-integer values")
        ids = raw.astype(np.int64)
        if len(np.unique(ids)) != len(ids):
            raise InputError(f"{frame.where}: column 'id' holds duplicate atom ids")
        frame_ids.append(ids)

    all_ids = np.unique(np.concatenate(frame_ids))
    num_frames, num_particles = len(frames), len(all_ids)
    positions = np.full((num_frames, num_particles, 3), np.nan, np.float32)
    velocities = np.full((num_frames, num_particles, 3), np.nan, np.float32)
    radii = np.full(num_particles, np.nan, np.float32)
    seen = np.zeros(num_particles, bool)
    for t, (frame, ids) in enumerate(zip(frames, frame_ids, strict=True)):
        slot = np.searchsorted(all_ids, ids)
        cols = [frame.columns.index(c) for c in REQUIRED_COLUMNS]
        values = frame.data[:, cols]
        positions[t, slot] = values[:, 1:4]
        velocities[t, slot] = values[:, 4:7]
        new = ~seen[slot]
        radii[slot[new]] = values[new, 7]
        seen[slot] = True

    first = frames[0].timestep
    times = np.array([(f.timestep - first) * float(dem_dt) for f in frames], np.float64)
    return {
        "positions": positions,
        "velocities": velocities,
        "radii": radii,
        "ids": all_ids.astype(np.int64),
        "times": times,
        "first_timestep": int(first),
    }


# --- parsing -------------------------------------------------------------------------------


class _Truncated(Exception):
    """The last frame of a file stops early; carries the message for warn/raise."""


@dataclass
class _Item:
    name: str  # e.g. "TIMESTEP", "BOX BOUNDS ff ff ff", "ATOMS id type x ..."
    line: int  # 1-based line of the "ITEM:" header
    start: int  # byte offset of the content (after the header line)
    end: int  # byte offset where the content ends (next header or end of file)
    at_eof: bool  # content runs to the end of the file
    complete: bool = True  # the header line ends with a newline

    @property
    def kind(self) -> str:
        for kind in _HEADER_ORDER:
            if self.name == kind or self.name.startswith(kind + " "):
                return kind
        return self.name.split(" ")[0] if self.name else ""


def _read_file(path: Path, on_truncated: str) -> list[DumpFrame]:
    raw = path.read_bytes()
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    cut_header = None
    tail_start = raw.rfind(b"\n") + 1
    tail = raw[tail_start:].strip()
    if tail and b"ITEM:".startswith(tail):  # the file ends inside an "ITEM:" keyword
        cut_header = _Truncated(f"{path}:{_last_line(raw)}: the file ends inside a frame header")
        raw = raw[:tail_start]
    frames = []
    groups = _group_frames(_find_items(raw, path), raw, path)
    for index, items in enumerate(groups):
        try:
            frames.append(_parse_frame(raw, path, items, last=index == len(groups) - 1))
        except _Truncated as err:
            _report_truncated(err, on_truncated)
    if cut_header is not None:
        _report_truncated(cut_header, on_truncated)
    return frames


def _report_truncated(err: _Truncated, on_truncated: str) -> None:
    message = f"{err}; the run was probably interrupted while writing"
    if on_truncated == "raise":
        raise InputError(
            f"{message}: regenerate the file or pass on_truncated='warn' to drop the frame"
        ) from None
    warnings.warn(f"{message}: dropping this frame", stacklevel=4)


def _find_items(raw: bytes, path: Path) -> list[_Item]:
    """Locate every ``ITEM:`` header line; line numbers are counted incrementally (fast)."""
    items: list[_Item] = []
    pos, line, counted_to = 0, 1, 0
    first = raw.find(b"ITEM:")
    if first < 0 and raw.strip():
        raise InputError(f"{path}:1: no 'ITEM:' header found; this is not a LIGGGHTS dump file")
    if first > 0 and raw[:first].strip():
        raise InputError(
            f"{path}:1: text before the first 'ITEM:' header; this is not a LIGGGHTS dump file"
        )
    while True:
        start = raw.find(b"ITEM:", pos)
        if start < 0:
            break
        line += raw.count(b"\n", counted_to, start)
        counted_to = start
        if start > 0 and raw[start - 1] != 0x0A:
            raise InputError(
                f"{path}:{line}: 'ITEM:' in the middle of a line; the file is corrupt (two "
                "writers at once?), regenerate it"
            )
        eol = raw.find(b"\n", start)
        header_end = len(raw) if eol < 0 else eol
        name = " ".join(raw[start + 5 : header_end].decode("ascii", "replace").split())
        content = min(header_end + 1, len(raw))
        if items:
            items[-1].end = start
            items[-1].at_eof = False
        items.append(_Item(name, line, content, len(raw), True, eol >= 0))
        pos = content
    return items


def _group_frames(items: list[_Item], raw: bytes, path: Path) -> list[list[_Item]]:
    """Split items into frames, each starting at ``ITEM: TIMESTEP``."""
    groups: list[list[_Item]] = []
    for item in items:
        if item.kind == "TIMESTEP":
            groups.append([item])
        elif groups:
            groups[-1].append(item)
        elif item.kind in _HEADER_ORDER:
            raise InputError(
                f"{path}:{item.line}: 'ITEM: {item.name}' before any 'ITEM: TIMESTEP'; the file "
                "does not start with a frame header, regenerate it"
            )
        # other items before the first TIMESTEP (UNITS, TIME, ...) are skipped
    return groups


def _parse_frame(raw: bytes, path: Path, items: list[_Item], last: bool) -> DumpFrame:
    by_kind: dict[str, _Item] = {}
    for item in items:
        if item.kind in _HEADER_ORDER:
            if item.kind in by_kind:
                raise InputError(
                    f"{path}:{item.line}: second 'ITEM: {item.kind}' in the frame starting at "
                    f"line {items[0].line}; the file is corrupt, regenerate it"
                )
            by_kind[item.kind] = item
    head = items[0]
    if not items[-1].complete and last:
        raise _Truncated(
            f"{path}:{items[-1].line}: the file ends inside the header 'ITEM: {items[-1].name}' "
            f"of the frame starting at line {head.line}"
        )
    missing = [kind for kind in _HEADER_ORDER if kind not in by_kind]
    if missing:
        present = [item.kind for item in items if item.kind in _HEADER_ORDER]
        cut = items[-1].at_eof and present == list(_HEADER_ORDER[: len(present)])
        message = (
            f"{path}:{head.line}: the frame starting here has no 'ITEM: {missing[0]}' "
            f"(file ends at line {_last_line(raw)})"
            if cut
            else f"{path}:{head.line}: the frame starting here has no 'ITEM: {missing[0]}'"
        )
        if cut and last:
            raise _Truncated(message.replace("has no", "is truncated: no"))
        raise InputError(f"{message}; the file is corrupt, regenerate it")

    timestep = _integer(raw, path, by_kind["TIMESTEP"], "timestep")
    num_atoms = _integer(raw, path, by_kind["NUMBER OF ATOMS"], "number of atoms")
    box = _box(raw, path, by_kind["BOX BOUNDS"])
    atoms = by_kind["ATOMS"]
    columns = atoms.name.split()[1:]
    if "id" not in columns:
        raise InputError(
            f"{path}:{atoms.line}: 'ITEM: {atoms.name}' has no 'id' column; write it in the "
            f"dump, e.g. '{_DUMP_HINT}'"
        )
    if len(set(columns)) != len(columns):
        raise InputError(f"{path}:{atoms.line}: 'ITEM: {atoms.name}' repeats a column name")
    data = _atoms(raw, path, atoms, columns, num_atoms, timestep)
    return DumpFrame(timestep, box, columns, data, str(path), head.line)


def _integer(raw: bytes, path: Path, item: _Item, what: str) -> int:
    tokens = raw[item.start : item.end].split()
    if not tokens and item.at_eof:
        raise _Truncated(f"{path}:{item.line}: 'ITEM: {item.name}' is truncated: no {what}")
    try:
        if len(tokens) != 1:
            raise ValueError
        return int(tokens[0])
    except ValueError:
        raise InputError(
            f"{path}:{item.line + 1}: expected one integer ({what}) after 'ITEM: {item.name}', "
            f"got {b' '.join(tokens[:4]).decode('ascii', 'replace')!r}; the file is corrupt, "
            "regenerate it"
        ) from None


def _box(raw: bytes, path: Path, item: _Item) -> np.ndarray:
    lines = [ln for ln in raw[item.start : item.end].split(b"\n") if ln.strip()]
    complete = raw[item.start : item.end].endswith(b"\n") or not item.at_eof
    if item.at_eof and (len(lines) < 3 or (len(lines) == 3 and not complete)):
        raise _Truncated(
            f"{path}:{item.line}: 'ITEM: {item.name}' is truncated at line {_last_line(raw)}"
        )
    bounds = []
    for k, line in enumerate(lines):
        tokens = line.split()
        try:
            if k >= 3 or len(tokens) not in (2, 3):
                raise ValueError
            bounds.append([float(tokens[0]), float(tokens[1])])
        except ValueError:
            raise InputError(
                f"{path}:{item.line + 1 + k}: expected three lines 'lo hi' after "
                f"'ITEM: {item.name}', got {line.decode('ascii', 'replace')!r}"
            ) from None
    if len(bounds) != 3:
        raise InputError(
            f"{path}:{item.line}: expected three lines 'lo hi' after 'ITEM: {item.name}', got "
            f"{len(bounds)}; the file is corrupt, regenerate it"
        )
    return np.array(bounds, np.float64)


def _atoms(
    raw: bytes, path: Path, item: _Item, columns: list[str], num_atoms: int, timestep: int
) -> np.ndarray:
    ncols = len(columns)
    block = raw[item.start : item.end]
    if not block.strip():
        data = np.empty((0, ncols), np.float64)
    else:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                data = np.loadtxt(io.BytesIO(block), dtype=np.float64, ndmin=2, comments=None)
        except (ValueError, Warning):
            data = None
        if data is None or data.shape[1] != ncols:
            _diagnose(block, path, item, columns, num_atoms, timestep)
            raise InputError(f"{path}:{item.line}: unreadable atom block; regenerate the file")
    if len(data) < num_atoms:
        where = f"{path}:{item.line}: TIMESTEP {timestep} lists {len(data)} atom line(s) of the "
        if item.at_eof:
            raise _Truncated(
                f"{where}{num_atoms} in its NUMBER OF ATOMS; truncated at line {_last_line(raw)}"
            )
        raise InputError(
            f"{where}{num_atoms} in its NUMBER OF ATOMS; the file is corrupt, regenerate it"
        )
    if len(data) > num_atoms:
        extra = _line_of_row(block, num_atoms) + item.line + 1
        raise InputError(
            f"{path}:{extra}: TIMESTEP {timestep} has more atom lines than its NUMBER OF ATOMS "
            f"({num_atoms}); the file is corrupt, regenerate it"
        )
    return data


def _diagnose(
    block: bytes, path: Path, item: _Item, columns: list[str], num_atoms: int, timestep: int
) -> None:
    """Find the first bad atom line (slow; only after the fast parser failed) and raise."""
    ncols = len(columns)
    lines = block.split(b"\n")
    last_nonblank = max((k for k, ln in enumerate(lines) if ln.strip()), default=-1)
    for k, line in enumerate(lines):
        tokens = line.split()
        if not tokens:
            continue
        lineno = item.line + 1 + k
        text = line.decode("ascii", "replace").strip()
        if len(tokens) < ncols and item.at_eof and k == last_nonblank:
            raise _Truncated(
                f"{path}:{lineno}: TIMESTEP {timestep} is truncated: its last atom line has "
                f"{len(tokens)} of {ncols} values"
            )
        if len(tokens) != ncols:
            raise InputError(
                f"{path}:{lineno}: expected {ncols} values ({' '.join(columns)}), found "
                f"{len(tokens)} in {text!r}; the file is corrupt, regenerate it"
            )
        for col, token in zip(columns, tokens, strict=True):
            try:
                float(token)
            except ValueError:
                raise InputError(
                    f"{path}:{lineno}: column {col!r} holds {token.decode('ascii', 'replace')!r}, "
                    "not a number; the file is corrupt, regenerate it"
                ) from None


def _line_of_row(block: bytes, row: int) -> int:
    """0-based line index in ``block`` of its ``row``-th non-blank line."""
    count = -1
    for k, line in enumerate(block.split(b"\n")):
        if line.strip():
            count += 1
            if count == row:
                return k
    return 0


def _last_line(raw: bytes) -> int:
    """1-based number of the last non-empty line of the file."""
    return raw.rstrip().count(b"\n") + 1
