"""Running LIGGGHTS on a Scene: input rendering, running, dump parsing (users' own runs:
:mod:`granular_pyg.dem_import`)."""

from granular_pyg.dem.dump import DumpFrame, frames_to_arrays, read_dump
from granular_pyg.dem.liggghts import DemRun, LiggghtsError, render_input, run_liggghts
from granular_pyg.dem.simulate import simulate

__all__ = [
    "DemRun",
    "DumpFrame",
    "LiggghtsError",
    "frames_to_arrays",
    "read_dump",
    "render_input",
    "run_liggghts",
    "simulate",
]
