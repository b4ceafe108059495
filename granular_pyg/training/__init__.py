"""Lightning: the data module, the training module and callbacks (Lightning lives only here)."""

from granular_pyg.training.callbacks import RolloutValidation
from granular_pyg.training.data_module import TrajectoryDataModule
from granular_pyg.training.module import SimulatorModule

__all__ = ["RolloutValidation", "SimulatorModule", "TrajectoryDataModule"]
