"""PushForward: the one-step loss on states the model itself has rolled forward (LagrangeBench)."""

from __future__ import annotations

import torch
from torch_geometric.data import Batch

from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.objectives.base import Objective, learned_steps, masked_mse

__all__ = ["PushForward"]


class PushForward(Objective):
    """Roll each window ``u ~ U{1..max_steps}`` steps forward with the model (no gradient), then
    take the one-step loss on the step after, so the model learns from its own slightly wrong
    inputs. As in a rollout, particles the model moves below the outflow leave; the loss covers
    the particles still present in the ground truth one step on.

    Args:
        max_steps: the largest push ``u`` (learned steps).
        share: fraction of the batches that take it in a Mixture.
    """

    def __init__(self, max_steps: int = 3, share: float = 0.5) -> None:
        super().__init__(share)
        self.max_steps = learned_steps("push_forward.max_steps", max_steps)

    @property
    def future_frames(self) -> int:
        return self.max_steps

    def pushed(self, sim: LearnedSimulator, batch: Batch, unroll: int) -> Batch:
        """The batch's windows rolled ``unroll`` model steps forward, with graphs and targets
        (NaN for particles that the ground truth has lost by then) rebuilt."""
        graphs, dt = [], float(sim.dt)
        for w in batch.windows:
            seq, props = w.pos_seq, w.props
            known = torch.cat([w.target_pos[:, None], w.future], dim=1)  # t + k, t + 2k, ...
            with torch.no_grad():
                for u in range(unroll):
                    nxt = sim.step(seq, w.walls, w.time + u * dt, w.outflow_z, props=props)
                    seq = torch.cat([seq[:, 1:], nxt[:, None]], dim=1)
            held = torch.isfinite(seq).all(dim=2).all(dim=1)  # not yet left in the model's run
            if bool(held.any()):
                seq, target, time = seq[held], known[held, unroll], w.time + unroll * dt
                props = props[held] if props is not None else None
            else:  # every particle left: the window's own step instead
                seq, target, time = w.pos_seq, w.target_pos, w.time
            frame = getattr(w, "frame", None)  # the window's augmentation frame, if any
            graph = sim.build_graph(seq, w.walls, time, props=props, frame=frame)
            graph.y = sim.target_acceleration(seq, target, frame)
            graphs.append(graph)
        return Batch.from_data_list(graphs).to(batch.x.device)

    def loss(self, sim: LearnedSimulator, batch: Batch, generator: torch.Generator) -> torch.Tensor:
        unroll = int(torch.randint(1, self.max_steps + 1, (1,), generator=generator))
        pushed = self.pushed(sim, batch, unroll)
        return masked_mse(sim(pushed), pushed.y)
