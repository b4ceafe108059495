"""File formats: atomic writes (here), HDF5 trajectories and VTK export (later issues)."""

from granular_pyg.io.atomic import atomic_write

__all__ = ["atomic_write"]
