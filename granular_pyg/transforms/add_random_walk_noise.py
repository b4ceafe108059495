"""Random-walk noise on the position history (GNS), optionally kept out of the walls (BGNN)."""

from __future__ import annotations

import math

import torch
from torch_geometric.data import Data
from torch_geometric.transforms import BaseTransform

from granular_pyg.errors import InputError

__all__ = ["AddRandomWalkNoise"]


class AddRandomWalkNoise(BaseTransform):
    r"""Perturb the position history with a random walk, as GNS trains against drift.

    Per particle, the per-frame displacements (velocities times the step) of the ``H``
    history steps get independent Gaussian increments of std :math:`\sigma / \sqrt{H}`,
    accumulated over time, so the last velocity's noise has std :math:`\sigma` (m per step);
    positions integrate that noise from zero at the oldest frame. By default the target is
    shifted by the last position's noise (GNS): the model then learns to correct the noisy
    velocity back onto the true next one, and keeps the position noise. With
    ``correct_positions`` the target stays the clean next position, so the model learns to undo
    the position noise as well: to push apart particles that the noise pressed into each other
    (granular contacts, unlike GNS's fluids, have a hard core).

    ``offset_std`` adds a displacement held over the whole history (std per axis, m): the
    velocities stay clean and the target stays the clean next position, so the model learns to
    push a particle displaced at rest back from the geometry alone (a bed's stiffness: without
    it, a model trained on the random walk answers a particle held 0.5 mm into a lid with
    0.001 m/s^2).

    ``drift_std`` adds a second random walk, one for the whole window, shared by every
    particle (the last velocity's std, m per step), shifted so that the last position is clean,
    with the target clean: the model learns to stop a coherent motion of the bed that the truth
    does not have, within one step. Without it a model answers a settled bed on a closed lid
    whose last step sank at 7 mm/s by accelerating it downwards at 1-2 m/s^2 (the start of a
    discharge), so a held bed's first small sink becomes a flow through the lid.

    With ``walls`` set, a particle whose noisy current position lies on the other side of a
    wall triangle within ``wall_check`` than its clean position gets fresh noise, up to
    ``max_tries`` times, then none (BGNN resamples noise that would push a particle through a
    wall). The check uses the walls' pose at ``data.time``.

    Expects ``data.pos_seq [N, H + 1, 3]`` (m) and optionally ``data.target_pos [N, 3]``;
    updates both and sets ``data.pos`` to the noisy current position.

    Args:
        std: :math:`\sigma`, noise std of the last velocity as a displacement per step (m).
        resample_at_walls: resample noise that crosses a wall (needs ``data.walls``).
        wall_check: distance (m) within which triangles are checked; default 100 times the
            larger of ``std`` and ``offset_std``.
        max_tries: resampling rounds before giving up (noise zero for those particles).
        generator: optional ``torch.Generator`` for reproducible noise.
        correct_positions: keep the clean target (learn to undo position noise too).
        offset_std: std (m) of the displacement held over the history, never in the target.
        drift_std: last-velocity std (m per step) of the walk shared by the window's particles,
            never in the last position nor the target.
    """

    def __init__(
        self,
        std: float,
        resample_at_walls: bool = False,
        wall_check: float | None = None,
        max_tries: int = 5,
        generator: torch.Generator | None = None,
        correct_positions: bool = False,
        offset_std: float = 0.0,
        drift_std: float = 0.0,
    ) -> None:
        for name, value in (("std", std), ("offset_std", offset_std), ("drift_std", drift_std)):
            if not (value >= 0 and math.isfinite(value)):
                raise InputError(f"{name}: expected a finite noise level >= 0 (m), got {value!r}")
        self.std = float(std)
        self.offset_std = float(offset_std)
        self.drift_std = float(drift_std)
        self.resample_at_walls = bool(resample_at_walls)
        reach = 100.0 * max(self.std, self.offset_std)
        self.wall_check = float(wall_check) if wall_check is not None else reach
        self.max_tries = int(max_tries)
        self.generator = generator
        self.correct_positions = bool(correct_positions)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(std={self.std}, resample_at_walls={self.resample_at_walls}, "
            f"correct_positions={self.correct_positions}, offset_std={self.offset_std}, "
            f"drift_std={self.drift_std})"
        )

    def _random_walk(self, num: int, steps: int, std: float, like: torch.Tensor) -> torch.Tensor:
        """``[num, steps + 1, 3]`` positions (m) of ``num`` random walks, zero at the oldest
        frame, whose velocities per step gain Gaussian increments of std ``std / sqrt(steps)``
        (so the last velocity's std is ``std``, m per step)."""
        increments = torch.randn(
            (num, steps, 3), generator=self.generator, dtype=like.dtype, device=like.device
        )
        velocity_noise = torch.cumsum(increments * (std / math.sqrt(max(steps, 1))), dim=1)
        return torch.cat([like.new_zeros((num, 1, 3)), torch.cumsum(velocity_noise, dim=1)], 1)

    def _walk(self, shape, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``([N, H + 1, 3], [N, 1, 3])``: the random walk (zero at the oldest frame) and the
        held offset (zeros without ``offset_std``, drawing nothing: the walk's draws are as
        before)."""
        num = shape[0]
        walk = self._random_walk(num, shape[1] - 1, self.std, like)
        offset = like.new_zeros((num, 1, 3))
        if self.offset_std > 0:
            offset = self.offset_std * torch.randn(
                (num, 1, 3), generator=self.generator, dtype=like.dtype, device=like.device
            )
        return walk, offset

    def _drift(self, seq: torch.Tensor) -> torch.Tensor:
        """``[1, H + 1, 3]``: one random walk for every particle (last velocity std
        ``drift_std``, m per step), minus its last frame, so the last position is unchanged
        (zeros without ``drift_std``, drawing nothing). Drawn after the per-particle walk and
        the offset, so these are as without it."""
        if self.drift_std <= 0:
            return seq.new_zeros((1, seq.shape[1], 3))
        walk = self._random_walk(1, seq.shape[1] - 1, self.drift_std, seq)
        return walk - walk[:, -1:]

    def _crossing(self, data: Data, clean: torch.Tensor, noisy: torch.Tensor) -> torch.Tensor:
        """``[N]`` bool: the noisy position is across a near triangle's plane from the clean."""
        if self.wall_check <= 0:
            return torch.zeros(clean.shape[0], dtype=torch.bool)
        near = data.walls.contacts(clean, self.wall_check, float(data.time))
        side_clean = ((clean[near.point_idx] - near.closest) * near.normal).sum(-1)
        side_noisy = ((noisy[near.point_idx] - near.closest) * near.normal).sum(-1)
        crossed = torch.zeros(clean.shape[0], dtype=torch.bool)
        crossed[near.point_idx[(side_clean * side_noisy) < 0]] = True
        return crossed

    def forward(self, data: Data) -> Data:
        seq = data.pos_seq
        walk, offset = self._walk(seq.shape, seq)
        if self.resample_at_walls and (self.std > 0 or self.offset_std > 0):
            clean = seq[:, -1]
            redo = self._crossing(data, clean, clean + walk[:, -1] + offset[:, -1])
            for _ in range(self.max_tries):
                if not bool(redo.any()):
                    break
                walk[redo], offset[redo] = self._walk((int(redo.sum()), seq.shape[1]), seq)
                redo = redo & self._crossing(data, clean, clean + walk[:, -1] + offset[:, -1])
            walk[redo], offset[redo] = 0.0, 0.0
        data.pos_seq = seq + walk + offset + self._drift(seq)
        data.pos = data.pos_seq[:, -1]
        if "target_pos" in data and not self.correct_positions:
            data.target_pos = data.target_pos + walk[:, -1]
        return data
