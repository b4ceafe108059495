"""Training objectives, chosen by the Hydra group ``objective`` (``conf/objective/``)."""

from granular_pyg.training.objectives.base import Objective, masked_mse
from granular_pyg.training.objectives.mixture import Mixture
from granular_pyg.training.objectives.one_step import OneStep
from granular_pyg.training.objectives.push_forward import PushForward
from granular_pyg.training.objectives.unrolled import Unrolled

__all__ = ["Mixture", "Objective", "OneStep", "PushForward", "Unrolled", "masked_mse"]
