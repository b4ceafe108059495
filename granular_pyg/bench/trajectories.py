"""Where a suite's trajectory comes from: a file, or ``sample:<kind>`` for a bundled one."""

from __future__ import annotations

from granular_pyg.errors import InputError
from granular_pyg.io import Trajectory, read_trajectory
from granular_pyg.samples import sample_files

__all__ = ["resolve_trajectory"]


def resolve_trajectory(source: str) -> Trajectory:
    """Read ``source``: an HDF5 trajectory path, or ``sample:hopper`` / ``sample:drum`` (the
    bundled test trajectory of that kind)."""
    source = str(source)
    if source.startswith("sample:"):
        kind = source.removeprefix("sample:")
        if kind not in ("hopper", "drum"):
            raise InputError(f"{source}: expected sample:hopper or sample:drum")
        return read_trajectory(sample_files(kind, "test")[0])
    return read_trajectory(source)
