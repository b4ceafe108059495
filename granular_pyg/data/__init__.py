"""Training data: windows of trajectories and their normalisation statistics (no Lightning)."""

from granular_pyg.data.statistics import NormalizationStats, compute_statistics
from granular_pyg.data.windows import Window, WindowDataset, load_split

__all__ = ["NormalizationStats", "Window", "WindowDataset", "compute_statistics", "load_split"]
