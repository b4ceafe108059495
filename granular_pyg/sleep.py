"""Sleeping particles: a bed at rest stays at rest until news of a change reaches it.

A settled bed in the DEM is held by contact forces that balance gravity; a network that
predicts accelerations would have to output zero there to about 0.01 m/s^2 (0.1% of g) for the
bed to stay put for seconds, and no training measured so far came within 0.1 m/s^2 (a bed on a
closed lid sank through it). Rigid-body engines meet the same problem by letting bodies at rest
*sleep* and waking them when something near them changes; the learned simulator does the same
(``model.sleep``):

* a particle is **awake** when it moved in its history (faster than :data:`REST_SPEED` in some
  step: not :func:`at_rest`), when it lies within the model's message-passing reach of an awake
  particle (:func:`spread`: ``num_steps`` hops over the particle edges, what a learned step can
  know), or within that reach of a wall that moves, is removed, or starts, stops or reverses its
  motion during the step (:meth:`~granular_pyg.simulator.LearnedSimulator.woken_by_walls`);
* every other particle **sleeps**: its acceleration is exactly zero, so its velocity stays zero
  and its position stays the same to the bit.

A bed released by its lid's removal wakes where the lid was, falls, and wakes the particles
above it as it goes; a bed nothing disturbs never wakes. A flowing bed is all awake: sleeping
changes nothing there. The rule holds outside training passes (training learns every
particle's acceleration), is the same in any frame (speeds and hop counts are invariant), and
needs no weights, so it can be switched on for any trained model.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["REST_SPEED", "at_rest", "spread"]

#: A particle whose history moves slower than this (m/s) at every step is at rest.
REST_SPEED = 1e-3


def at_rest(pos_seq: Tensor, dt: float) -> Tensor:
    """``[N]`` bool: the particles of ``pos_seq [N, H + 1, 3]`` (m, a learned step ``dt`` (s)
    apart) that move slower than :data:`REST_SPEED` in every step of their history."""
    step = torch.linalg.vector_norm(pos_seq.diff(dim=1), dim=-1)
    return (step < REST_SPEED * dt).all(dim=1)


def spread(awake: Tensor, edge_index: Tensor, is_wall: Tensor, hops: int) -> Tensor:
    """``[N + W]`` bool: the nodes within ``hops`` particle-to-particle edges of an ``awake``
    one (``awake [N + W]`` bool, ``edge_index [2, E]`` source -> target, ``is_wall [N + W]``);
    news does not pass through wall nodes."""
    src, dst = edge_index
    between = ~(is_wall[src] | is_wall[dst])
    src, dst = src[between], dst[between]
    for _ in range(hops):
        reached = torch.zeros(awake.shape[0], dtype=torch.int32, device=awake.device)
        reached.index_add_(0, dst, awake[src].to(torch.int32))
        grown = awake | (reached > 0)
        if torch.equal(grown, awake):
            break
        awake = grown
    return awake
