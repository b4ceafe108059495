"""Several ``dump custom`` files (a fill run, a discharge run, ...) stitched into one sequence.

LIGGGHTS runs are often split: a fill run and a discharge run, each with its own ``dump``
command, or one dump re-created after an ``undump``. Their frames are merged here in TIMESTEP
order:

* a TIMESTEP written twice (the last frame of one dump and the first of the next, e.g. at the
  ``run`` boundary) is kept once when both copies hold the same atoms with the same values, and
  refused when they differ (two different runs were mixed);
* the frames must then be evenly spaced: a missing frame (a gap) or an odd spacing is refused
  with a message naming the TIMESTEPs around it, so uneven frame spacing is never produced
  silently (:func:`read_dumps`);
* or, asked for (``convert --split-gaps``), the frames are cut into runs of evenly spaced frames
  (:func:`read_dump_runs`, :func:`evenly_spaced_runs`), each of which becomes a trajectory.
"""

from __future__ import annotations

import itertools
import os
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from granular_pyg.dem.dump import REQUIRED_COLUMNS, DumpFrame, read_dump
from granular_pyg.errors import InputError

__all__ = ["dump_files", "evenly_spaced_runs", "frame_spacing", "read_dump_runs", "read_dumps"]


def dump_files(
    paths: Sequence[str | os.PathLike],
    pattern: str = "*",
    suffixes: Sequence[str] | None = None,
    what: str = "dump",
    option: str = "--pattern",
) -> list[Path]:
    """The files named by ``paths``: files as given, folders expanded to the regular files
    whose names match ``pattern`` (and end in one of ``suffixes``, case-insensitive, when
    given), sorted by name. ``what`` and ``option`` name the files and the pattern's option in
    the messages.

    Raises:
        FileNotFoundError: a path does not exist.
        InputError: a folder holds no matching file, or no path was given.
    """
    if not paths:
        raise InputError(f"{what}s: no {what} file or folder given; pass at least one")
    described = "files" if suffixes is None else " or ".join(suffixes) + " files"
    files: list[Path] = []
    for given in paths:
        path = Path(given)
        if path.is_dir():
            found = sorted(
                p
                for p in path.glob(pattern)
                if p.is_file() and (suffixes is None or p.suffix.lower() in suffixes)
            )
            if not found:
                raise InputError(
                    f"{path}: no {described} match {pattern!r} in this folder; check the "
                    f"folder or {option}"
                )
            files += found
        elif path.is_file():
            files.append(path)
        else:
            raise FileNotFoundError(f"{path}: no such {what} file or folder; check the path")
    return files


def read_dumps(
    paths: Sequence[str | os.PathLike] | str | os.PathLike,
    on_truncated: str = "warn",
    pattern: str = "*",
) -> list[DumpFrame]:
    """Read and stitch every frame of several dump files and folders.

    Args:
        paths: dump files and/or folders of dump files (a single path is accepted too).
        on_truncated: what to do with a truncated last frame of a file (see
            :func:`granular_pyg.dem.dump.read_dump`).
        pattern: glob for file names in folders.

    Returns:
        The frames in strictly increasing TIMESTEP order, evenly spaced, duplicates dropped.

    Raises:
        FileNotFoundError: a path does not exist.
        InputError: a malformed file, a TIMESTEP written twice with different contents, or
            frames that are not evenly spaced (a missing frame); the message names the files
            and TIMESTEPs.
    """
    merged = _stitched(paths, on_truncated, pattern)
    frame_spacing(merged)
    return merged


def read_dump_runs(
    paths: Sequence[str | os.PathLike] | str | os.PathLike,
    on_truncated: str = "warn",
    pattern: str = "*",
) -> list[list[DumpFrame]]:
    """Read and stitch every frame like :func:`read_dumps`, but cut the frames into runs of
    evenly spaced frames (:func:`evenly_spaced_runs`) instead of refusing a gap.

    Returns:
        The runs in TIMESTEP order (one run when the frames are evenly spaced).

    Raises:
        FileNotFoundError: a path does not exist.
        InputError: a malformed file, or a TIMESTEP written twice with different contents.
    """
    return evenly_spaced_runs(_stitched(paths, on_truncated, pattern))


def evenly_spaced_runs(frames: Sequence[DumpFrame]) -> list[list[DumpFrame]]:
    """Cut ``frames`` (strictly increasing TIMESTEPs) into runs of evenly spaced frames.

    Runs are taken from the first frame on, each as long as the spacing of its first step
    lasts; a missing frame or a change of spacing ends it. A frame that would end a two-frame
    run while it starts a run of three or more frames of another spacing goes to that longer
    run (``700, 1000, 1100, 1200`` -> ``[700], [1000, 1100, 1200]``).

    Returns:
        The runs, in order; together they hold every frame once. A single frame is a run of 1.
    """
    steps = [b.timestep - a.timestep for a, b in itertools.pairwise(frames)]
    runs: list[list[DumpFrame]] = []
    start = 0
    while start < len(frames):
        end = start + 1  # the run is frames[start:end]
        if end < len(frames):
            spacing = steps[start]
            end += 1
            while end < len(frames) and steps[end - 1] == spacing:
                end += 1
            # frames[end - 1] ends a two-frame run but starts a longer one: it goes there
            if end - start == 2 and end + 1 < len(frames) and steps[end - 1] == steps[end]:
                end -= 1
        runs.append(list(frames[start:end]))
        start = end
    return runs


def _stitched(
    paths: Sequence[str | os.PathLike] | str | os.PathLike, on_truncated: str, pattern: str
) -> list[DumpFrame]:
    """Every frame of the dump files in TIMESTEP order, a TIMESTEP written twice kept once."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    frames: list[DumpFrame] = []
    for path in dump_files(paths, pattern):
        frames += read_dump(path, on_truncated=on_truncated)
    frames.sort(key=lambda f: f.timestep)  # stable: the order given breaks ties
    merged: list[DumpFrame] = []
    for frame in frames:
        if merged and merged[-1].timestep == frame.timestep:
            _check_same(merged[-1], frame)
            continue
        merged.append(frame)
    return merged


def frame_spacing(frames: Sequence[DumpFrame]) -> int:
    """The common TIMESTEP spacing of ``frames`` (1 for a single frame).

    Raises:
        InputError: the spacing is not the same everywhere; the message names the TIMESTEPs
            (and files) on both sides of each odd step, and how many frames are missing where
            the step is a multiple of the regular one.
    """
    steps = np.diff([f.timestep for f in frames])
    if len(steps) == 0:
        return 1
    counts = Counter(int(s) for s in steps)
    regular = min(counts, key=lambda s: (-counts[s], s))  # the most common, ties: the smallest
    odd = [k for k, s in enumerate(steps) if s != regular]
    if not odd:
        return regular
    parts = []
    for k in odd[:3]:
        a, b = frames[k], frames[k + 1]
        step = b.timestep - a.timestep
        what = (
            f"{step // regular - 1} frame(s) missing"
            if step % regular == 0 and step > regular
            else f"a step of {step}"
        )
        parts.append(f"TIMESTEP {a.timestep} ({a.source}) -> {b.timestep} ({b.source}): {what}")
    more = f" (and {len(odd) - 3} more)" if len(odd) > 3 else ""
    raise InputError(
        f"dumps: frames must be evenly spaced, every {regular} steps, but "
        f"{'; '.join(parts)}{more}; add the missing dump files, or pass --split-gaps to write "
        "each evenly spaced run as its own trajectory"
    )


def _check_same(kept: DumpFrame, again: DumpFrame) -> None:
    """Refuse a TIMESTEP written twice with different atoms or values."""
    a, b = _sorted_values(kept), _sorted_values(again)
    where = f"dumps: TIMESTEP {kept.timestep} is written twice, in {kept.where} and {again.where}"
    if a is None or b is None:
        return  # a missing column is reported later, naming the frame
    if a.shape != b.shape or not np.array_equal(a[:, 0], b[:, 0]):
        only = np.setxor1d(a[:, 0], b[:, 0])
        first = f"; e.g. atom id {int(only[0])} is in one only" if len(only) else ""
        raise InputError(
            f"{where}, with different atoms ({len(a)} vs {len(b)}){first}: these dumps are not "
            "from one run; pass the dumps of one run only"
        )
    differ = ~((a == b) | (np.isnan(a) & np.isnan(b)))
    if differ.any():
        row, col = (int(i[0]) for i in np.nonzero(differ))
        name = REQUIRED_COLUMNS[col]
        raise InputError(
            f"{where}, with different values (atom id {int(a[row, 0])}: {name} = "
            f"{a[row, col]!r} vs {b[row, col]!r}): these dumps are not from one run; pass the "
            "dumps of one run only"
        )


def _sorted_values(frame: DumpFrame) -> np.ndarray | None:
    """``[n, 8]`` the required columns sorted by id, or None when one is missing."""
    if any(c not in frame.columns for c in REQUIRED_COLUMNS):
        return None
    values = frame.data[:, [frame.columns.index(c) for c in REQUIRED_COLUMNS]]
    return values[np.argsort(values[:, 0], kind="stable")]
