"""Objective: what a training step minimises, and how many future frames its windows need."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.errors import InputError
from granular_pyg.simulator import LearnedSimulator

__all__ = ["Objective", "learned_steps", "masked_mse"]


def learned_steps(name: str, value) -> int:
    """``value`` as a whole number of learned steps >= 1, or an InputError naming ``name``."""
    steps = int(value)
    if steps < 1 or steps != value:
        raise InputError(f"{name}: expected a whole number of learned steps >= 1, got {value!r}")
    return steps


def masked_mse(
    pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None
) -> torch.Tensor:
    """MSE over the rows of ``target [N, 3]`` without NaN (a particle the ground truth has lost);
    a zero that keeps the graph if every row is NaN. ``weight [N]`` (optional) scales each
    row's squared error; the mean is still over the rows, so weights of 1 give the plain MSE."""
    known = torch.isfinite(target).all(dim=1)
    if not bool(known.all()):
        if not bool(known.any()):
            return pred.sum() * 0.0
        pred, target = pred[known], target[known]
        weight = None if weight is None else weight[known]
    if weight is None:
        return torch.nn.functional.mse_loss(pred, target)
    return (weight.to(pred.dtype)[:, None] * (pred - target) ** 2).mean()


class Objective:
    """A training loss on a batch of windows.

    Args:
        share: fraction of the training batches that take this objective when it is part of a
            :class:`~granular_pyg.training.objectives.Mixture` (the rest take the one-step loss).
    """

    def __init__(self, share: float = 1.0) -> None:
        self.share = float(share)

    @property
    def future_frames(self) -> int:
        """Target frames each training window must hold after its first target (0: none)."""
        return 0

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        """The scalar loss of ``batch`` (its graphs, ``batch.windows``, ``batch.y``); draws any
        randomness from ``generator``."""
        raise NotImplementedError

    def __repr__(self) -> str:
        settings = ", ".join(f"{k}={v!r}" for k, v in vars(self).items())
        return f"{type(self).__name__}({settings})"
