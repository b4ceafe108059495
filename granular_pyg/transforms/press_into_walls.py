"""Training states pressed into the walls: teaches the model to push particles back out."""

from __future__ import annotations

import math

import torch
from torch_geometric.data import Data
from torch_geometric.transforms import BaseTransform

from granular_pyg.errors import InputError
from granular_pyg.geometry import argmin_per_group

__all__ = ["PressIntoWalls"]

#: Largest fraction of its distance to the wall plane that a centre is pressed: it stays on
#: the container's side (beyond the plane the wall node's features would point the other way).
MAX_PRESS_FRACTION = 0.9


class PressIntoWalls(BaseTransform):
    """Moves particles near a wall towards it, keeping the target where it was.

    A learned rollout's particles creep into the walls over several steps until their centres
    pass a triangle's plane, where the wall node's displacement flips and the model pushes them
    on through (measured on the hopper's leaks: they fall as if the wall were not there).
    LIGGGHTS never shows such states, so the model never learns to undo them. Here a particle
    whose centre is within ``reach`` of a wall triangle is, with probability ``fraction``,
    moved towards the closest point of its nearest triangle (at distance ``d``):

    - its whole history by ``U(0, 1) * min(depth, 0.9 * d)`` (an overlap), and
    - with ``approach`` > 0, each past frame ``j`` of ``H`` also back by
      ``(H - j) * U(0, approach)`` (a velocity into the wall of up to ``approach`` per frame).

    The target stays LIGGGHTS's next position, so the one-step target pushes the particle back
    out and stops its approach. (Measured: at the paper hopper's CPU budget this does not
    lower the rollouts' leaks; README, Results.)

    Expects ``data.pos_seq [N, H + 1, 3]`` (m), ``data.walls`` (a WallSet) and ``data.time``
    (s, the walls' pose); updates ``data.pos_seq`` and sets ``data.pressed [N]`` (m, how far
    the current position moved) and ``data.approach [N]`` (m per frame).

    Args:
        depth: the largest press (m), > 0.
        reach: particles whose centre is closer than this to a wall are candidates (m), > 0;
            about the particle radius plus ``depth``.
        fraction: probability that a candidate is pressed, in (0, 1].
        approach: the largest added velocity into the wall (m per frame of ``pos_seq``), >= 0.
        generator: optional ``torch.Generator`` for reproducible presses.
    """

    def __init__(
        self,
        depth: float,
        reach: float,
        fraction: float = 0.5,
        approach: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> None:
        for name, value in (("depth", depth), ("reach", reach)):
            if not (value > 0 and math.isfinite(value)):
                raise InputError(f"{name}: expected a positive distance (m), got {value!r}")
        if not 0 < fraction <= 1:
            raise InputError(f"fraction: expected a probability in (0, 1], got {fraction!r}")
        if not (approach >= 0 and math.isfinite(approach)):
            raise InputError(f"approach: expected a speed >= 0 (m per frame), got {approach!r}")
        self.depth, self.reach, self.fraction = float(depth), float(reach), float(fraction)
        self.approach = float(approach)
        self.generator = generator

    def __repr__(self) -> str:
        name = type(self).__name__
        return (
            f"{name}(depth={self.depth}, reach={self.reach}, fraction={self.fraction}, "
            f"approach={self.approach})"
        )

    def forward(self, data: Data) -> Data:
        seq = data.pos_seq
        num = seq.shape[0]
        pressed, approach = seq.new_zeros(num), seq.new_zeros(num)
        near = data.walls.contacts(seq[:, -1], self.reach, float(data.time))
        if near.point_idx.numel():
            offset = near.closest.to(seq.dtype) - seq[near.point_idx, -1]
            dist = torch.linalg.vector_norm(offset, dim=1)
            # The nearest triangle of each particle; coincident points are skipped.
            idx, nearest = argmin_per_group(dist, near.point_idx)
            apart = dist[nearest] > 0
            idx, offset, dist = idx[apart], offset[nearest[apart]], dist[nearest[apart]]
            draw = torch.rand((3, idx.numel()), generator=self.generator, dtype=seq.dtype)
            chosen = (draw[0] < self.fraction).to(seq.dtype)
            amount = chosen * draw[1] * torch.clamp(dist * MAX_PRESS_FRACTION, max=self.depth)
            speed = chosen * draw[2] * self.approach
            back = torch.arange(seq.shape[1] - 1, -1, -1, dtype=seq.dtype)  # H - j
            shift = amount.unsqueeze(1) - speed.unsqueeze(1) * back  # [P, H + 1] towards
            seq = seq.clone()
            seq[idx] += (offset / dist.unsqueeze(1)).unsqueeze(1) * shift.unsqueeze(2)
            pressed[idx], approach[idx] = amount, speed
        data.pos_seq = seq
        data.pos = seq[:, -1]
        data.pressed, data.approach = pressed, approach
        return data
