"""Mixture: the one documented rule that combines objectives over the training batches."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.errors import InputError
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives.base import Objective
from granular_pyg.training.objectives.one_step import OneStep

__all__ = ["Mixture"]


class Mixture(Objective):
    """Each training batch takes one objective: a number ``u`` in ``[0, 1)`` is drawn from the
    batch's generator (seeded by the run's seed and the global step, so a resumed run draws the
    same); the parts, in the order given, take consecutive intervals of ``u`` of width their
    ``share``; the batches left over take the one-step loss. The shares must add up to at most 1.

    ``Mixture({})`` is plain one-step training;
    ``Mixture({"unrolled": Unrolled(4, 0.5)})`` unrolls half the batches.

    Args:
        parts: ``{name: objective}``; names only label the parts (Hydra config keys).
    """

    def __init__(self, parts: dict[str, Objective] | None = None) -> None:
        super().__init__(1.0)
        self.parts = dict(parts or {})
        loose = [k for k, p in self.parts.items() if not isinstance(p, Objective)]
        if loose:
            raise InputError(
                f"objective.parts.{loose[0]}: settings without an objective (no _target_): "
                "an experiment tunes this part but the chosen objective group does not have "
                f"it; drop them with '~objective.parts.{loose[0]}' or choose an objective "
                "that has it (objective=unrolled, push_forward)"
            )
        total = sum(p.share for p in self.parts.values())
        if any(p.share < 0 for p in self.parts.values()) or total > 1.0 + 1e-9:
            shares = {k: p.share for k, p in self.parts.items()}
            raise InputError(
                f"objective shares {shares}: each must be >= 0 and together at most 1 "
                "(the rest of the batches take the one-step loss)"
            )
        self.rest = OneStep()

    @property
    def future_frames(self) -> int:
        return max([p.future_frames for p in self.parts.values()], default=0)

    def pick(self, generator: torch.Generator) -> Objective:
        """The objective of the next batch (draws ``u`` from ``generator`` once)."""
        u, start = float(torch.rand((), generator=generator, dtype=torch.float64)), 0.0
        for part in self.parts.values():
            if start <= u < start + part.share:
                return part
            start += part.share
        return self.rest

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        return self.pick(generator).loss(sim, batch, generator)
