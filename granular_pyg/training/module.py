"""SimulatorModule: noise-injected one-step training of a LearnedSimulator."""

from __future__ import annotations

import random

import lightning as L
import numpy as np
import torch
from torch_geometric.data import Batch

from granular_pyg.simulator import LearnedSimulator

__all__ = ["SimulatorModule"]


class SimulatorModule(L.LightningModule):
    """Trains a :class:`LearnedSimulator` on one-step targets (MSE of the normalised
    acceleration of real particles), with Adam and GNS's exponential learning-rate decay
    ``lr(s) = lr_final + (lr - lr_final) * 0.1 ** (s / decay_steps)``.

    Push-forward training (LagrangeBench): with ``push_forward_steps = p > 0``, a batch is, with
    probability ``push_forward_prob``, first rolled forward ``u ~ U{1..p}`` steps by the model
    itself (no gradient) and the loss taken on the step after, so the model learns from its own
    slightly wrong inputs. As in a rollout, particles the model moves below the outflow leave;
    the loss covers the particles still present in the ground truth one step on.

    The RNG states (python, numpy, torch) are saved in checkpoints and restored on resume, so a
    resumed run continues exactly.

    Args:
        simulator: the model.
        lr: initial learning rate.
        lr_final: asymptotic learning rate.
        decay_steps: optimiser steps per factor-10 decay.
        push_forward_steps: maximal push-forward unroll ``p`` (0: off).
        push_forward_prob: probability that a batch is pushed forward.
    """

    def __init__(
        self,
        simulator: LearnedSimulator,
        lr: float = 1e-4,
        lr_final: float = 1e-6,
        decay_steps: float = 1e5,
        push_forward_steps: int = 0,
        push_forward_prob: float = 0.0,
    ) -> None:
        super().__init__()
        self.sim = simulator
        self.lr, self.lr_final, self.decay_steps = float(lr), float(lr_final), float(decay_steps)
        self.push_forward_steps = int(push_forward_steps)
        self.push_forward_prob = float(push_forward_prob)

    def forward(self, batch: Batch) -> torch.Tensor:
        return self.sim(batch)

    def _loss(self, batch: Batch) -> torch.Tensor:
        pred, target = self.sim(batch), batch.y
        known = torch.isfinite(target).all(dim=1)  # NaN: left in the ground truth (push-forward)
        if not bool(known.all()):
            if not bool(known.any()):
                return pred.sum() * 0.0
            pred, target = pred[known], target[known]
        return torch.nn.functional.mse_loss(pred, target)

    def _pushed_forward(self, batch: Batch) -> Batch:
        """Roll each window forward ``u`` model steps and rebuild its graph and target (NaN for
        particles that the ground truth has lost by then)."""
        unroll = random.randint(1, self.push_forward_steps)
        graphs = []
        for w in batch.windows:
            seq = w.pos_seq
            known = torch.cat([w.target_pos[:, None], w.future], dim=1)  # t + k, t + 2k, ...
            dt = float(self.sim.dt)
            for u in range(unroll):
                nxt = self.sim.step(seq, w.walls, w.time + u * dt, w.outflow_z)
                seq = torch.cat([seq[:, 1:], nxt[:, None]], dim=1)
            held = torch.isfinite(seq).all(dim=2).all(dim=1)  # not yet left in the model's run
            if bool(held.any()):
                seq, target, time = seq[held], known[held, unroll], w.time + unroll * dt
            else:  # every particle left: the window's own step instead
                seq, target, time = w.pos_seq, w.target_pos, w.time
            graph = self.sim.build_graph(seq, w.walls, time)
            graph.y = self.sim.target_acceleration(seq, target)
            graphs.append(graph)
        return Batch.from_data_list(graphs).to(self.device)

    def training_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        if self.push_forward_steps and random.random() < self.push_forward_prob:
            batch = self._pushed_forward(batch)
        loss = self._loss(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.num_graphs, sync_dist=True)
        return loss

    def validation_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        loss = self._loss(batch)
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

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        states = checkpoint.get("rng_states")
        if states:
            random.setstate(states["python"])
            kind, keys, pos, has_gauss, cached = states["numpy"]
            np.random.set_state((kind, keys.numpy(), pos, has_gauss, cached))  # noqa: NPY002
            torch.set_rng_state(states["torch"])
