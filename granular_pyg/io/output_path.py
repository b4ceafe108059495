"""Checks on an output path before the work starts, so that nothing of the user's is lost."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable
from pathlib import Path

from granular_pyg.errors import InputError

__all__ = ["MIN_FREE_BYTES", "check_output"]

#: Free space an output folder must have before a command starts (bytes).
MIN_FREE_BYTES = 50 * 2**20


def _same_file(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def check_output(
    out: str | os.PathLike,
    inputs: Iterable[str | os.PathLike | None] = (),
    overwrite: bool = False,
    option: str = "out",
    min_free_bytes: int = MIN_FREE_BYTES,
    overwrite_option: str = "overwrite=true",
) -> Path:
    """Refuse an output file that would destroy an input or an earlier result, or that cannot
    be written, before any work is done.

    Args:
        out: the file to be written.
        inputs: files the command reads (None entries are skipped); ``out`` may be none of them
            (the same path, a link to it, or the folder that holds a dump).
        overwrite: allow replacing an existing ``out``.
        option: how the user names ``out`` (``out``, ``--out``), for the message.
        overwrite_option: how the user allows replacing it (``overwrite=true``,
            ``--overwrite``), for the message.
        min_free_bytes: free space the output folder needs.

    Returns:
        ``out`` as a Path. Its folder is created.

    Raises:
        InputError: ``out`` is an input or inside an input folder, exists without
            ``overwrite``, its folder cannot be created or written, or the disk is nearly full.
    """
    if not isinstance(overwrite, bool):  # "no" is a non-empty string: true to Python
        name = overwrite_option.split("=")[0]
        raise InputError(f"{name}: expected true or false, got {overwrite!r}")
    out = Path(out)
    for given in inputs:
        if given is None:
            continue
        source = Path(given)
        if _same_file(out, source) or (
            source.is_dir() and out.resolve().is_relative_to(source.resolve())
        ):
            raise InputError(
                f"{option}: {out} is the input {source}; choose another output file, the input "
                "is never overwritten"
            )
    if out.is_dir():
        raise InputError(f"{option}: {out} is a folder; name a file, e.g. {out / 'result.h5'}")
    if out.exists() and not overwrite:
        raise InputError(
            f"{option}: {out} exists; choose another file or pass {overwrite_option} to replace it"
        )
    folder = out.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option}: cannot create the folder {folder} ({exc.strerror})") from exc
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"{option}: the folder {folder} is not writable; choose another {option}")
    free = shutil.disk_usage(folder).free
    if free < min_free_bytes:
        raise InputError(
            f"{option}: only {free / 2**20:.0f} MiB free in {folder}; free some space or choose "
            f"another {option}"
        )
    return out
