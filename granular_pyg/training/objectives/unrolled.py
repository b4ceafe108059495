"""Unrolled: the position error along the model's own run, with gradients through it (BPTT)."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.errors import InputError
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives.base import Objective, learned_steps, masked_mse
from granular_pyg.training.reach_mask import within_reach_of_events

__all__ = ["Unrolled"]


class Unrolled(Objective):
    """Run each clean window ``steps`` steps with the model, gradients through the run; the loss
    is the mean over the steps of the one-step loss against the acceleration that would take the
    model's state to LIGGGHTS's next positions, i.e. of the position error along the model's own
    run (scaled by ``1 / (dt^2 acc_std)``). Particles leave through the outflow as in a rollout.
    With ``data.mask_beyond_reach``, a step near a wall event leaves out the particles beyond
    the model's reach of it, as the one-step loss does, and ends the run: after it, those
    particles' model state has missed the event (a bed still at rest where LIGGGHTS's has
    fallen), and the next steps' targets would ask a bed at rest, that nothing can tell of the
    event, to catch up.
    The edges and the walls' closest points are not differentiated: a wall edge's displacement
    carries the gradient of its particle's position only.

    Args:
        steps: learned steps ``m`` of the run (the windows hold ``m - 1`` future frames).
        share: fraction of the batches that take it in a Mixture.
    """

    def __init__(self, steps: int = 4, share: float = 0.5) -> None:
        super().__init__(share)
        self.steps = learned_steps("unrolled.steps", steps)

    @property
    def future_frames(self) -> int:
        return self.steps - 1

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        dt, steps, device = float(sim.dt), self.steps, batch.x.device
        mask = bool(getattr(batch, "mask_beyond_reach", False))
        acc_mean, acc_std = sim.acc_mean.double(), sim.acc_std.double()
        losses = []
        for w in batch.windows:
            future = getattr(w, "future", w.target_pos[:, None][:, :0])  # [N, 0, 3] if none
            if future.shape[1] < steps - 1:
                raise InputError(
                    f"the unrolled objective with steps={steps} needs {steps - 1} future frames "
                    f"per window, the windows hold {future.shape[1]}: attach the data module "
                    "with this objective (TrajectoryDataModule.attach(sim, objective))"
                )
            seq = w.pos_seq.to(device, torch.float64)
            known = torch.cat([w.target_pos[:, None], future], 1).to(device, torch.float64)
            props, frame = w.props, getattr(w, "frame", None)
            for u in range(steps):
                t = w.time + u * dt
                acc = sim.predict_acceleration(seq, w.walls, t, props=props, frame=frame).double()
                pred = (acc - acc_mean) / acc_std
                target = sim.target_acceleration(seq, known[:, u]).double()
                missed = False
                if mask:
                    reached = within_reach_of_events(w.walls, seq[:, -1].detach(), t, dt, sim.reach)
                    target[~reached.to(device)] = float("nan")
                    missed = not bool(reached.all())
                losses.append(masked_mse(pred, target))
                if u + 1 == steps or missed:
                    break
                nxt = sim.integrate(seq, acc)
                held = nxt[:, 2] >= w.outflow_z if w.outflow_z is not None else None
                seq = torch.cat([seq[:, 1:], nxt[:, None]], dim=1)
                if held is not None:
                    if not bool(held.any()):
                        break  # every particle left through the outflow
                    seq, known = seq[held], known[held]
                    props = props[held] if props is not None else None
        return torch.stack(losses).mean().float()
