"""Which particles a learned step can know a wall event from: ``data.mask_beyond_reach``."""

from __future__ import annotations

import torch

from granular_pyg.scenes import WallSet

__all__ = ["within_reach_of_events"]


def within_reach_of_events(
    walls: WallSet, points: torch.Tensor, time: float, dt: float, reach: float
) -> torch.Tensor:
    """``[N]`` bool: the particles whose target a model of ``reach`` (m: message-passing steps
    x cut-off) can know, for the learned step of ``dt`` (s) from recorded time ``time`` (s)
    with the particles at ``points [N, 3]`` (m).

    A wall removed, or a motion started, stopped or reversed, within the step or within the
    history's last step reaches, by the step's end, only the particles within ``reach`` of that
    wall; the rest of the bed is at rest in its history, or moves by a fraction of a mm/s, as
    in the steps without the event, and a loss on it teaches the mix of both: a bed at rest
    that sinks, and a bed that starts to sink sped up. All True when no event is that near.
    """
    changed = walls.changing(time - dt, time + dt)
    if not changed:
        return torch.ones(points.shape[0], dtype=torch.bool)
    return walls.near(points, reach, time, changed)
