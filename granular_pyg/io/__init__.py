"""File formats: atomic writes, output checks, HDF5 trajectories, ParaView export, Markdown."""

from granular_pyg.io.atomic import atomic_path, atomic_write
from granular_pyg.io.markdown import command_header, command_line, markdown_table
from granular_pyg.io.output_path import check_output
from granular_pyg.io.trajectory import Trajectory, read_trajectory, write_trajectory
from granular_pyg.io.vtk import export_paraview, read_vtp, write_pvd, write_vtp

__all__ = [
    "Trajectory",
    "atomic_path",
    "atomic_write",
    "check_output",
    "command_header",
    "command_line",
    "export_paraview",
    "markdown_table",
    "read_trajectory",
    "read_vtp",
    "write_pvd",
    "write_trajectory",
    "write_vtp",
]
