"""File formats: atomic writes, HDF5 trajectories (VTK export arrives later)."""

from granular_pyg.io.atomic import atomic_path, atomic_write
from granular_pyg.io.trajectory import Trajectory, read_trajectory, write_trajectory

__all__ = ["Trajectory", "atomic_path", "atomic_write", "read_trajectory", "write_trajectory"]
