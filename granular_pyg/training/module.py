"""SimulatorModule: noise-injected training of a LearnedSimulator with a chosen objective."""

from __future__ import annotations

import contextlib
import random
from collections.abc import Iterator

import lightning as L
import numpy as np
import torch
from torch_geometric.data import Batch

from granular_pyg.errors import positive_number
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives import Mixture, Objective, OneStep, masked_mse
from granular_pyg.training.weight_average import WeightAverage

__all__ = ["SimulatorModule"]


class SimulatorModule(L.LightningModule):
    """Trains a :class:`LearnedSimulator` with an
    :class:`~granular_pyg.training.objectives.Objective` (default: the one-step MSE of the
    normalised acceleration of real particles), Adam and GNS's exponential learning-rate decay
    ``lr(s) = lr_final + (lr - lr_final) * 0.1 ** (s / decay_steps)``.

    The objective's randomness (which part of a Mixture a batch takes, push-forward's push) is
    drawn from a generator seeded by ``(seed, global step)``, and the RNG states (python, numpy,
    torch) are saved in checkpoints and restored on resume, so a resumed run continues exactly.

    With ``ema_decay`` the model's weights are also averaged over the optimiser steps
    (:class:`~granular_pyg.training.weight_average.WeightAverage`); validation epochs and
    validation rollouts run with the average (:meth:`averaged_weights`), and a checkpoint's
    ``state_dict`` holds the average (what evaluation, rollouts, export and fine-tuning load)
    with the raw weights under ``raw_weights`` for an exact resume.

    Args:
        simulator: the model.
        objective: the training loss (None: one-step).
        lr: initial learning rate.
        lr_final: asymptotic learning rate.
        decay_steps: optimiser steps per factor-10 decay.
        seed: seed of the objective's draws.
        ema_decay: decay of the weight average (0.999: about the last 1,000 steps); 0 for
            none.
    """

    def __init__(
        self,
        simulator: LearnedSimulator,
        objective: Objective | None = None,
        lr: float = 1e-4,
        lr_final: float = 1e-6,
        decay_steps: float = 1e5,
        seed: int = 0,
        ema_decay: float = 0.0,
    ) -> None:
        super().__init__()
        self.sim = simulator
        self.objective = objective if objective is not None else OneStep()
        self.lr = positive_number("optim.lr", lr)
        self.lr_final = positive_number("optim.lr_final", lr_final)
        self.decay_steps = positive_number("optim.decay_steps", decay_steps)
        self.seed = int(seed)
        self.average = WeightAverage(ema_decay) if ema_decay else None
        self._raw: dict[str, torch.Tensor] | None = None  # the raw weights while validating

    def forward(self, batch: Batch) -> torch.Tensor:
        return self.sim(batch)

    def _generator(self) -> torch.Generator:
        """The objective's generator for this optimiser step (the same on resume)."""
        return torch.Generator().manual_seed(self.seed * 1_000_003 + int(self.global_step))

    def training_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        loss = self.objective.loss(self.sim, batch, self._generator())
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.num_graphs, sync_dist=True)
        # Each objective's loss apart (its epoch mean over the batches it took): a mixture's
        # parts differ by orders of magnitude, and their sum hides which one moves.
        self.log(
            f"train/loss_{self.objective_name()}",
            loss.detach(),
            on_step=False,
            on_epoch=True,
            batch_size=batch.num_graphs,
            sync_dist=True,
        )
        return loss

    def objective_name(self) -> str:
        """The name of the objective this optimiser step's batch takes: a
        :class:`~granular_pyg.training.objectives.Mixture` part's config key (``unrolled``,
        ``push_forward``) or ``one_step`` for the rest; another objective's class name in
        snake case. Draws from its own copy of the step's generator, so the loss's draws do not
        change."""
        objective = self.objective
        if isinstance(objective, Mixture):
            picked = objective.pick(self._generator())
            for name, part in objective.parts.items():
                if part is picked:
                    return name
            return "one_step"
        name = type(objective).__name__
        return "".join(f"_{c.lower()}" if c.isupper() else c for c in name).lstrip("_")

    def optimizer_step(self, *args, **kwargs) -> None:
        """The optimiser's step, then the average's (before any checkpoint of the step)."""
        super().optimizer_step(*args, **kwargs)
        if self.average is not None:
            self.average.update(self.sim)

    def on_validation_start(self) -> None:
        """Validate with the averaged weights (losses and the rollouts after the epoch)."""
        self._average_in()

    def on_validation_end(self) -> None:
        self._raw_back()

    @contextlib.contextmanager
    def averaged_weights(self) -> Iterator[None]:
        """The averaged weights in the model within the block, the raw ones back after it (a
        rollout due by steps or seconds in the training loop sees what validation sees); a
        no-op without an average or while they already are in."""
        swapped = self._average_in()
        try:
            yield
        finally:
            if swapped:
                self._raw_back()

    def _average_in(self) -> bool:
        """Put the average in, keeping the raw weights aside; False if there was nothing to do."""
        if self.average is None or self.average.params is None or self._raw is not None:
            return False
        self._raw = self._parameters_now()
        self._put(self.average.params)
        return True

    def _raw_back(self) -> None:
        if self._raw is not None:
            self._put(self._raw)
            self._raw = None

    def _parameters_now(self) -> dict[str, torch.Tensor]:
        return {name: p.detach().clone() for name, p in self.sim.named_parameters()}

    @torch.no_grad()
    def _put(self, params: dict[str, torch.Tensor]) -> None:
        for name, p in self.sim.named_parameters():
            p.copy_(params[name])

    def validation_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        loss = masked_mse(self.sim(batch), batch.y)
        self.log("val/loss", loss, prog_bar=True, batch_size=batch.num_graphs, sync_dist=True)
        return loss

    def configure_optimizers(self):
        optimizer = torch.optim.Adam(self.parameters(), lr=self.lr)
        ratio = self.lr_final / self.lr

        def schedule(step: int) -> float:
            return ratio + (1.0 - ratio) * 0.1 ** (step / self.decay_steps)

        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, schedule)
        return {
            "optimizer": optimizer,
            "lr_scheduler": {"scheduler": scheduler, "interval": "step"},
        }

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        # Plain types and tensors only, so that Lightning's weights-only loading accepts them.
        kind, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002 (global RNG)
        checkpoint["rng_states"] = {
            "python": random.getstate(),
            "numpy": (kind, torch.from_numpy(keys.copy()), int(pos), int(has_gauss), float(cached)),
            "torch": torch.get_rng_state(),
        }
        if self.average is not None and self.average.params is not None:
            raw = self._raw if self._raw is not None else self._parameters_now()
            state = checkpoint["state_dict"]
            checkpoint["raw_weights"] = {f"sim.{k}": v for k, v in raw.items()}  # fresh copies
            for name, value in self.average.params.items():
                state[f"sim.{name}"] = value.detach().clone()

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        # Before the state dict is loaded: the run goes on from its raw weights, the average
        # from the saved (averaged) ones; without ema_decay now, the average is dropped.
        raw = checkpoint.pop("raw_weights", None)
        if raw is not None:
            state = checkpoint["state_dict"]
            if self.average is not None:
                averaged = {k[len("sim.") :]: state[k] for k in raw}
                self.average.load(averaged, self.sim)
            state.update(raw)
        states = checkpoint.get("rng_states")
        if states:
            random.setstate(states["python"])
            kind, keys, pos, has_gauss, cached = states["numpy"]
            np.random.set_state((kind, keys.numpy(), pos, has_gauss, cached))  # noqa: NPY002
            torch.set_rng_state(states["torch"])
