"""OneStep: GNS's loss, the MSE of the normalised one-step acceleration."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.nn.rest_gate import gate_hinge
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives.base import Objective, masked_mse

__all__ = ["OneStep"]


class OneStep(Objective):
    """MSE between the predicted and the target normalised acceleration ``batch.y [N, 3]`` of
    the real particles (NaN targets, particles the ground truth has lost, left out), each
    particle weighted by ``batch.weight [N]`` where the batch has one (``data.rest_weight``);
    with a rest gate, plus the gate's hinge on its labels ``batch.gate_label [N]``
    (:func:`~granular_pyg.nn.rest_gate.gate_hinge`), from the same network pass."""

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        pred, logits = sim.forward_with_gate(batch)
        loss = masked_mse(pred, batch.y, getattr(batch, "weight", None))
        labels = getattr(batch, "gate_label", None)
        if logits is not None and labels is not None:
            loss = loss + gate_hinge(logits, labels.to(logits.device))
        return loss
