"""One training batch of the bundled hopper and its loss and gradients, for the tests that
compare a training step's variants (bf16 autocast, torch.compile) with the plain one."""

from __future__ import annotations

import torch
from hydra.utils import instantiate

from granular_pyg.config import compose


def model_objective_batch(overrides: list[str]):
    """``(simulator, objective, batch)`` of the training config with ``overrides``."""
    cfg = compose("train", overrides)
    sim, objective, data = instantiate(cfg.model), instantiate(cfg.objective), instantiate(cfg.data)
    data.attach(sim, objective)
    return sim, objective, next(iter(data.train_dataloader()))


def loss_and_grads(sim, objective, batch, autocast: bool = False) -> tuple[float, torch.Tensor]:
    """The objective's loss on ``batch`` and every parameter's gradient, flattened, concatenated."""
    sim.zero_grad()
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        loss = objective.loss(sim, batch, torch.Generator().manual_seed(0))
    loss.backward()
    return float(loss.detach()), torch.cat([p.grad.flatten() for p in sim.parameters()])
