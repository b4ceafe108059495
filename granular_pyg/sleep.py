"""Sleeping particles: a bed at rest stays at rest until news of a change reaches it.

A settled bed in the DEM is held by contact forces that balance gravity; a network that
predicts accelerations would have to output zero there to about 0.01 m/s^2 (0.1% of g) for the
bed to stay put for seconds, and no training measured so far came within 0.1 m/s^2 (a bed on a
closed lid sank through it). Rigid-body engines meet the same problem by letting bodies at rest
*sleep* and waking them when something near them changes; the learned simulator does the same
(``model.sleep``):

* a particle is **awake** when it moved in its history (faster than :data:`REST_SPEED` in some
  step: not :func:`at_rest`), when the network gives it more than :data:`WAKE_ACCELERATION`,
  when no node of its graph (a particle or a wall's closest point within the cut-off) lies
  beneath it (:func:`supported`: nothing to rest on, as a bed packed in mid-air at a fill's
  start, which the network may not see fall), when it lies within the model's message-passing
  reach of awake particles (:func:`spread`: ``num_steps`` hops over the particle edges, what a
  learned step can know; a hop needs :data:`QUORUM` awake neighbours, as a bed mobilises
  together while a lone particle still settling in its cage, a rattler, moves nothing), or
  within that reach of a wall that moves, is removed, or starts, stops or reverses its motion
  during the step
  (:meth:`~granular_pyg.simulator.LearnedSimulator.woken_by_walls`);
* every other particle **sleeps**: its acceleration is exactly zero, so its velocity stays zero
  and its position stays the same to the bit.

A bed released by its lid's removal wakes where the lid was, falls, and wakes the particles
above it as it goes; a bed nothing disturbs never wakes. A flowing bed is all awake: sleeping
changes nothing there. Without the quorum, a recorded bed whose history holds one rattler woke
around it, and the network's error at rest (0.1-2 m/s^2 in the models measured) carried the
wake through the bed and the bed through its lid. The rule holds outside training passes
(training learns every particle's acceleration), is the same in any frame (speeds and hop
counts are invariant), and needs no weights, so it can be switched on for any trained model.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = [
    "QUORUM",
    "REST_SPEED",
    "SUPPORT_ANGLE_DEG",
    "WAKE_ACCELERATION",
    "at_rest",
    "spread",
    "supported",
]

#: A particle whose history moves slower than this (m/s) at every step is at rest.
REST_SPEED = 1e-3

#: Awake neighbours that wake a particle at rest: more than one, so that a rattler does not.
QUORUM = 2

#: A particle the network gives more than this acceleration (m/s^2, half of standard gravity)
#: is awake: one without support falls at g, while every shipped or candidate model gives a
#: settled bed's particles at most 2.1 m/s^2 (``docs/results.md``).
WAKE_ACCELERATION = 0.5 * 9.80665


def at_rest(pos_seq: Tensor, dt: float) -> Tensor:
    """``[N]`` bool: the particles of ``pos_seq [N, H + 1, 3]`` (m, a learned step ``dt`` (s)
    apart) that move slower than :data:`REST_SPEED` in every step of their history."""
    step = torch.linalg.vector_norm(pos_seq.diff(dim=1), dim=-1)
    return (step < REST_SPEED * dt).all(dim=1)


def spread(
    awake: Tensor, edge_index: Tensor, is_wall: Tensor, hops: int, quorum: int = 1
) -> Tensor:
    """``[N + W]`` bool: ``awake [N + W]`` grown ``hops`` times, each time by the nodes with at
    least ``quorum`` awake neighbours over the particle-to-particle edges (``edge_index
    [2, E]`` source -> target, ``is_wall [N + W]``); news does not pass through wall nodes.
    With ``quorum`` 1: the nodes within ``hops`` edges of an awake one."""
    src, dst = edge_index
    between = ~(is_wall[src] | is_wall[dst])
    src, dst = src[between], dst[between]
    for _ in range(hops):
        reached = torch.zeros(awake.shape[0], dtype=torch.int32, device=awake.device)
        reached.index_add_(0, dst, awake[src].to(torch.int32))
        grown = awake | (reached >= quorum)
        if torch.equal(grown, awake):
            break
        awake = grown
    return awake


#: A neighbour supports a node when it lies at least this far below the horizontal through the
#: node (degrees): a contact beneath it, not a neighbour in its own layer.
SUPPORT_ANGLE_DEG = 30.0


def supported(pos: Tensor, edge_index: Tensor) -> Tensor:
    """``[N + W]`` bool: the nodes at ``pos [N + W, 3]`` (m, gravity along -z) with a neighbour
    (``edge_index [2, E]``, source -> target, both ways) at least :data:`SUPPORT_ANGLE_DEG`
    below their horizontal: something they can rest on."""
    src, dst = edge_index
    offset = pos[dst] - pos[src]  # from the neighbour up to the node
    sine = math.sin(math.radians(SUPPORT_ANGLE_DEG))
    below = offset[:, 2] > sine * torch.linalg.vector_norm(offset, dim=1)
    count = torch.zeros(pos.shape[0], dtype=torch.int32, device=pos.device)
    count.index_add_(0, dst[below], torch.ones_like(dst[below], dtype=torch.int32))
    return count > 0
