"""Segment-triangle crossings: which straight moves ``start -> end`` pass through a triangle.

The wall guard of a rollout (:meth:`granular_pyg.scenes.WallSet.contain`) uses them to find
particle centres that a learned step carried through a wall.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

__all__ = ["SegmentCrossings", "segment_triangle_crossings"]

# Relative slack on the inside-the-triangle test, so a move through a shared edge is never lost.
_EDGE_SLACK = 1e-9


class SegmentCrossings(NamedTuple):
    """Crossings of ``K`` (segment, triangle) pairs.

    Attributes:
        crosses: ``[K]`` bool, the segment passes through the triangle: it starts off the
            triangle's plane and ends on it or past it, through the triangle or its edges.
        fraction: ``[K]`` where along the segment the crossing lies, in ``[0, 1]`` (NaN where
            ``crosses`` is False).
        normal: ``[K, 3]`` unit normal of the triangle, pointing to the side the segment starts
            on (zero for degenerate triangles and starts on the plane).
        start_distance: ``[K]`` distance of the start from the triangle's plane (m).
        end_depth: ``[K]`` how far the end lies past the plane (m), ``>= -skin`` where
            ``crosses``.
    """

    crosses: torch.Tensor
    fraction: torch.Tensor
    normal: torch.Tensor
    start_distance: torch.Tensor
    end_depth: torch.Tensor


def segment_triangle_crossings(
    start: torch.Tensor,
    end: torch.Tensor,
    triangles: torch.Tensor,
    skin: torch.Tensor | float = 0.0,
) -> SegmentCrossings:
    """Whether each segment ``start[k] -> end[k]`` crosses triangle ``triangles[k]``.

    A segment that starts exactly on the plane has no side and never crosses; degenerate
    (zero-area) triangles are never crossed. With ``skin`` > 0 a segment that ends on its
    start's side closer than ``skin`` to the plane, over the triangle, counts as crossing too
    (at ``fraction`` 1, with a negative ``end_depth``): the wall guard's margin against
    round-off.

    Args:
        start: ``[K, 3]`` segment starts (m).
        end: ``[K, 3]`` segment ends (m).
        triangles: ``[K, 3, 3]`` triangle vertices (m).
        skin: ``[K]`` or a float >= 0 (m).

    Returns:
        :class:`SegmentCrossings`, in the dtype of ``start``.
    """
    v0, v1, v2 = triangles.unbind(1)
    e1, e2 = v1 - v0, v2 - v0
    cross = torch.linalg.cross(e1, e2)
    twice_area = torch.linalg.vector_norm(cross, dim=1)
    scale = torch.maximum(torch.linalg.vector_norm(e1, dim=1), torch.linalg.vector_norm(e2, dim=1))
    proper = twice_area > 1e-12 * scale.square()
    unit = cross / torch.where(proper, twice_area, 1.0).unsqueeze(1)
    a = ((start - v0) * unit).sum(1)  # signed distance of the start
    b = ((end - v0) * unit).sum(1)  # signed distance of the end
    side = torch.sign(a)
    depth = -side * b  # > 0: the end lies past the plane
    through = depth >= 0
    changes = proper & (a != 0) & (depth >= -torch.as_tensor(skin, dtype=depth.dtype))
    fraction = torch.where(through, a / torch.where(changes & through, a - b, 1.0), 1.0)
    # Where the segment passes the plane; a move that stops in the skin: its end's foot.
    hit = torch.where(
        through.unsqueeze(1),
        start + fraction.unsqueeze(1) * (end - start),
        end - b.unsqueeze(1) * unit,
    )
    inside = _inside(hit - v0, e1, e2)
    crosses = changes & inside
    return SegmentCrossings(
        crosses=crosses,
        fraction=torch.where(crosses, fraction, torch.nan),
        normal=unit * torch.where(proper, side, 0.0).unsqueeze(1),
        start_distance=a.abs(),
        end_depth=depth,
    )


def _inside(rel: torch.Tensor, e1: torch.Tensor, e2: torch.Tensor) -> torch.Tensor:
    """Whether points ``v0 + rel`` in the triangle's plane lie in it (edges included)."""
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    r1, r2 = (rel * e1).sum(1), (rel * e2).sum(1)
    det = d11 * d22 - d12 * d12
    safe = torch.where(det > 0, det, 1.0)
    u = (d22 * r1 - d12 * r2) / safe
    v = (d11 * r2 - d12 * r1) / safe
    return (det > 0) & (u >= -_EDGE_SLACK) & (v >= -_EDGE_SLACK) & (u + v <= 1 + _EDGE_SLACK)
