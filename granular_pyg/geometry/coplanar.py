"""One wall node per surface patch, whatever the mesh's triangulation.

The paper puts one virtual node on every triangle within the cut-off. On a finely triangulated
wall (a CAD export, the rim of an outlet, a 48-facet cylinder) a particle then sees tens of
nodes where a coarse mesh of the same surface gives it one or two: the model's input depends
on how the mesh was cut, not on the wall. Here a particle's contact is dropped when its closest
point lies on the plane of a closer contact of the same particle (within a tolerance): the
neighbours of a flat floor's nearest triangle all touch the particle at points of that floor's
plane, so one node is left per plane, and a curved wall keeps one node wherever it has turned
away from the nearer nodes' planes by more than the tolerance.
"""

from __future__ import annotations

import torch

from granular_pyg.errors import InputError

__all__ = ["coplanar_redundant"]


def coplanar_redundant(
    points: torch.Tensor,
    point_idx: torch.Tensor,
    closest: torch.Tensor,
    normal: torch.Tensor,
    tolerance: float,
) -> torch.Tensor:
    """``[K]`` bool: the particle-triangle contacts another contact of the same particle makes
    redundant.

    Contact ``j`` of particle ``i`` is redundant when some contact ``m`` of ``i`` is closer to
    ``i`` (ties: the earlier row) and ``j``'s closest point lies within ``tolerance`` of ``m``'s
    plane: ``|n_m . (c_j - c_m)| <= tolerance``. The closest contact of every particle is kept.

    Args:
        points: ``[P, 3]`` particle centres (m).
        point_idx: ``[K]`` int64 particle of each contact.
        closest: ``[K, 3]`` closest point on each contact's triangle (m).
        normal: ``[K, 3]`` unit normal of each contact's triangle (either orientation).
        tolerance: distance from a plane (m) within which a point counts as on it; >= 0.

    Returns:
        ``[K]`` bool, True for contacts to drop.
    """
    if not tolerance >= 0:
        raise InputError(f"tolerance: expected a distance >= 0 (m), got {tolerance!r}")
    num = point_idx.numel()
    if num == 0:
        return torch.zeros(0, dtype=torch.bool, device=point_idx.device)
    dist = torch.linalg.vector_norm(points[point_idx] - closest, dim=1)
    # Order by particle, then distance, then row: each contact is paired with those before it.
    by_dist = torch.sort(dist, stable=True).indices
    order = by_dist[torch.sort(point_idx[by_dist], stable=True).indices]
    group = point_idx[order]
    counts = torch.unique_consecutive(group, return_counts=True)[1]
    starts = torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
    rank = torch.arange(num, device=order.device) - starts  # closer contacts of the same particle
    later = torch.repeat_interleave(torch.arange(num, device=order.device), rank)
    offset = torch.arange(later.numel(), device=order.device)
    offset = offset - torch.repeat_interleave(torch.cumsum(rank, 0) - rank, rank)
    earlier = starts[later] + offset
    j, m = order[later], order[earlier]
    off_plane = ((closest[j] - closest[m]) * normal[m]).sum(dim=1).abs()
    redundant = torch.zeros(num, dtype=torch.bool, device=point_idx.device)
    redundant[j[off_plane <= tolerance]] = True
    return redundant
