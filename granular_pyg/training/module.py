"""SimulatorModule: noise-injected one-step training of a LearnedSimulator."""

from __future__ import annotations

import random

import lightning as L
import numpy as np
import torch
from torch_geometric.data import Batch

from granular_pyg.errors import InputError
from granular_pyg.simulator import LearnedSimulator

__all__ = ["SimulatorModule"]


def _masked_mse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """MSE over the rows of ``target [N, 3]`` without NaN (a particle the ground truth has lost);
    a zero that keeps the graph if every row is NaN."""
    known = torch.isfinite(target).all(dim=1)
    if not bool(known.all()):
        if not bool(known.any()):
            return pred.sum() * 0.0
        pred, target = pred[known], target[known]
    return torch.nn.functional.mse_loss(pred, target)


class SimulatorModule(L.LightningModule):
    """Trains a :class:`LearnedSimulator` on one-step targets (MSE of the normalised
    acceleration of real particles), with Adam and GNS's exponential learning-rate decay
    ``lr(s) = lr_final + (lr - lr_final) * 0.1 ** (s / decay_steps)``.

    Push-forward training (LagrangeBench): with ``push_forward_steps = p > 0``, a batch is, with
    probability ``push_forward_prob``, first rolled forward ``u ~ U{1..p}`` steps by the model
    itself (no gradient) and the loss taken on the step after, so the model learns from its own
    slightly wrong inputs. As in a rollout, particles the model moves below the outflow leave;
    the loss covers the particles still present in the ground truth one step on.

    Unrolled training (backpropagation through time): with ``unroll_steps = m > 0``, a batch is,
    with probability ``unroll_prob``, run ``m`` steps by the model from its clean windows, with
    gradients through the run; the loss is the mean over the steps of the one-step loss against
    the acceleration that would take the model's state to LIGGGHTS's next positions, i.e. of the
    position error along the model's own run (scaled by ``1 / (dt^2 acc_std)``). Particles leave
    through the outflow as in a rollout. The edges and the walls' closest points are not
    differentiated: a wall edge's displacement carries the gradient of its particle's position
    only.

    The RNG states (python, numpy, torch) are saved in checkpoints and restored on resume, so a
    resumed run continues exactly.

    Args:
        simulator: the model.
        lr: initial learning rate.
        lr_final: asymptotic learning rate.
        decay_steps: optimiser steps per factor-10 decay.
        push_forward_steps: maximal push-forward unroll ``p`` (0: off).
        push_forward_prob: probability that a batch is pushed forward.
        unroll_steps: steps ``m`` of the unrolled loss (0: off; the windows need ``m - 1``
            future frames, which ``TrajectoryDataModule(unroll_steps=m)`` keeps).
        unroll_prob: probability that a batch takes the unrolled loss.
        unroll_noise: start the unrolled run from the batch's noisy inputs instead of the clean
            window (the targets stay LIGGGHTS's positions, as with ``noise_target=position``).
    """

    def __init__(
        self,
        simulator: LearnedSimulator,
        lr: float = 1e-4,
        lr_final: float = 1e-6,
        decay_steps: float = 1e5,
        push_forward_steps: int = 0,
        push_forward_prob: float = 0.0,
        unroll_steps: int = 0,
        unroll_prob: float = 0.0,
        unroll_noise: bool = False,
    ) -> None:
        super().__init__()
        self.sim = simulator
        self.lr, self.lr_final, self.decay_steps = float(lr), float(lr_final), float(decay_steps)
        self.push_forward_steps = int(push_forward_steps)
        self.push_forward_prob = float(push_forward_prob)
        self.unroll_steps, self.unroll_prob = int(unroll_steps), float(unroll_prob)
        self.unroll_noise = bool(unroll_noise)
        if self.unroll_steps < 0 or not 0.0 <= self.unroll_prob <= 1.0:
            raise InputError(
                f"unroll_steps / unroll_prob: expected steps >= 0 and a probability in [0, 1], "
                f"got {unroll_steps!r} / {unroll_prob!r}"
            )

    def forward(self, batch: Batch) -> torch.Tensor:
        return self.sim(batch)

    def _loss(self, batch: Batch) -> torch.Tensor:
        return _masked_mse(self.sim(batch), batch.y)

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

    def _unrolled_loss(self, batch: Batch) -> torch.Tensor:
        """Mean over ``unroll_steps`` steps of the model's own run from each window (clean, or
        with ``unroll_noise`` the batch's noisy inputs) of the normalised one-step loss, with
        gradients through the run (see the class docstring)."""
        sim, dt, steps = self.sim, float(self.sim.dt), self.unroll_steps
        acc_mean, acc_std = sim.acc_mean.double(), sim.acc_std.double()
        losses = []
        starts = batch.noisy_pos_seqs if self.unroll_noise else [w.pos_seq for w in batch.windows]
        for w, start in zip(batch.windows, starts, strict=True):
            future = getattr(w, "future", w.target_pos[:, None][:, :0])  # [N, 0, 3] if none
            if future.shape[1] < steps - 1:
                raise InputError(
                    f"unroll_steps={steps} needs {steps - 1} future frames per window, the "
                    f"windows hold {future.shape[1]}: build the data with "
                    f"unroll_steps={steps} (the train config passes push_forward.unroll_steps)"
                )
            seq = start.to(self.device, torch.float64)
            known = torch.cat([w.target_pos[:, None], future], 1).to(self.device, torch.float64)
            for u in range(steps):
                acc = sim.predict_acceleration(seq, w.walls, w.time + u * dt).double()
                pred = (acc - acc_mean) / acc_std
                losses.append(_masked_mse(pred, sim.target_acceleration(seq, known[:, u]).double()))
                if u + 1 == steps:
                    break
                nxt = sim.integrate(seq, acc)
                held = nxt[:, 2] >= w.outflow_z if w.outflow_z is not None else None
                seq = torch.cat([seq[:, 1:], nxt[:, None]], dim=1)
                if held is not None:
                    if not bool(held.any()):
                        break  # every particle left through the outflow
                    seq, known = seq[held], known[held]
        return torch.stack(losses).mean().float()

    def training_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        if self.unroll_steps and random.random() < self.unroll_prob:
            loss = self._unrolled_loss(batch)
        else:
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
