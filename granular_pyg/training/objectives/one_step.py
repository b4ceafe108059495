"""OneStep: GNS's loss, the MSE of the normalised one-step acceleration."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives.base import Objective, masked_mse

__all__ = ["OneStep"]


class OneStep(Objective):
    """MSE between the predicted and the target normalised acceleration ``batch.y [N, 3]`` of
    the real particles (NaN targets, particles the ground truth has lost, left out), each
    particle weighted by ``batch.weight [N]`` where the batch has one (``data.rest_weight``)."""

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        return masked_mse(sim(batch), batch.y, getattr(batch, "weight", None))
