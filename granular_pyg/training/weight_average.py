"""An exponential moving average of a model's weights over the optimiser steps.

A one-step model's resting bias swings from checkpoint to checkpoint (the last steps' noisy
gradients move it); the average over the last ``1 / (1 - decay)`` steps keeps their common
part. Training saves the average as the model's weights (what evaluation, rollouts and
fine-tuning load) and keeps the raw weights beside it for an exact resume, see
:class:`~granular_pyg.training.SimulatorModule`.
"""

from __future__ import annotations

import torch
from torch import nn

from granular_pyg.errors import InputError

__all__ = ["WeightAverage"]


class WeightAverage:
    """``average <- decay * average + (1 - decay) * weights`` after each optimiser step, per
    parameter (buffers such as the normalisation statistics are not averaged).

    Args:
        decay: in ``(0, 1)``; the average spans about ``1 / (1 - decay)`` steps.

    The average starts as the weights at the first :meth:`update` (or as restored by
    :meth:`load`), so it needs no bias correction.
    """

    def __init__(self, decay: float) -> None:
        decay = float(decay)
        if not 0.0 < decay < 1.0:
            raise InputError(
                f"optim.ema_decay: expected a number in (0, 1) (0.999: about the last 1,000 "
                f"steps) or 0 for no average, got {decay!r}"
            )
        self.decay = decay
        self.params: dict[str, torch.Tensor] | None = None

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
        """Fold the module's current parameters into the average."""
        current = dict(module.named_parameters())
        if self.params is None:
            self.params = {name: p.detach().clone() for name, p in current.items()}
            return
        for name, avg in self.params.items():
            avg.lerp_(current[name].detach(), 1.0 - self.decay)

    def load(self, params: dict[str, torch.Tensor], module: nn.Module) -> None:
        """Restore the average from ``params`` (parameter name -> tensor, as :meth:`update`
        names them), placed like the module's parameters."""
        own = dict(module.named_parameters())
        if set(params) != set(own):
            raise InputError(
                "the checkpoint's averaged weights do not match the model's parameters; resume "
                "with the config the run was started with"
            )
        self.params = {name: params[name].to(own[name]).clone() for name in own}
