"""Lightning: the data module, the training module and callbacks (Lightning lives only here)."""

import warnings

from granular_pyg.training.callbacks import RolloutValidation
from granular_pyg.training.checkpoint_io import AtomicCheckpointIO
from granular_pyg.training.data_module import TrajectoryDataModule
from granular_pyg.training.module import SimulatorModule

# Lightning 2.6 on torch 2.13 warns about its own pytree helper on every fit; not actionable.
warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated")

__all__ = ["AtomicCheckpointIO", "RolloutValidation", "SimulatorModule", "TrajectoryDataModule"]
