r"""Closest point on a triangle to a point, vectorised over pairs (Eberly's region method).

A triangle is parametrised as :math:`T(s, t) = B + s E_0 + t E_1` with :math:`B = v_0`,
:math:`E_0 = v_1 - v_0`, :math:`E_1 = v_2 - v_0` and :math:`s, t \ge 0,\ s + t \le 1`.
With :math:`D = B - P` the unconstrained minimiser of :math:`|T(s, t) - P|^2` is
:math:`(\bar s, \bar t) = (be - cd,\ bd - ae) / \det` where :math:`a = E_0 \cdot E_0`,
:math:`b = E_0 \cdot E_1`, :math:`c = E_1 \cdot E_1`, :math:`d = E_0 \cdot D`,
:math:`e = E_1 \cdot D` and :math:`\det = ac - b^2`. Eberly ("Distance Between Point and
Triangle in 3D", Geometric Tools) splits the :math:`(s, t)` plane into seven regions::

        t
        ^
     \ 2|
      \ |
       \|
        |\
        | \   1
      3 | 0\
        |   \
    ----+----\-----> s
      4 | 5   \  6

Region 0 is the interior (the projection is the answer); regions 1, 3 and 5 project onto one
edge; regions 2, 4 and 6 lie beyond a vertex and pick one of its two edges by the sign of a
directional derivative. We evaluate the same formulas with the Lagrange identity
:math:`\det = |N|^2`, :math:`\bar s \det = N \cdot (E_1 \times D)`,
:math:`\bar t \det = N \cdot (D \times E_0)` with :math:`N = E_0 \times E_1`, which is
algebraically identical but keeps float32 accurate on thin triangles (no cancellation in
:math:`ac - b^2`).

Degenerate triangles (zero area: repeated or collinear vertices) have no interior; for them the
answer is the closest point over the three edges, each a segment that may itself be a point.
"""

from __future__ import annotations

import torch

from granular_pyg.errors import InputError, check_tensor

__all__ = ["closest_point_on_segments", "closest_point_on_triangles", "triangle_regions"]

# A triangle counts as degenerate when sin^2 of its angle at v0 is below this many machine
# epsilons squared: its (s, t) would then be dominated by round-off.
_DEGENERATE_EPS_FACTOR = 64.0


#: Largest float32 coordinate (m) computed in float32: Eberly's determinant grows as the fourth
#: power of the edge lengths and overflows float32 beyond about 1e9 m; larger inputs are
#: computed in float64 (with ``validate``, which looks at every coordinate anyway).
FLOAT32_SAFE_COORDINATE = 1e8


# The kernels below work on structure-of-arrays vectors: a tuple of three contiguous ``[P]``
# tensors. On the CPU this is 2-3x faster than reducing over a trailing dimension of size 3.
Vec = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


def _soa(x: torch.Tensor) -> Vec:
    """``[P, 3]`` -> three contiguous ``[P]`` components."""
    return tuple(x.T.contiguous().unbind(0))  # type: ignore[return-value]


def _sub(x: Vec, y: Vec) -> Vec:
    return (x[0] - y[0], x[1] - y[1], x[2] - y[2])


def _dot(x: Vec, y: Vec) -> torch.Tensor:
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


def _cross(x: Vec, y: Vec) -> Vec:
    return (
        x[1] * y[2] - x[2] * y[1],
        x[2] * y[0] - x[0] * y[2],
        x[0] * y[1] - x[1] * y[0],
    )


def _clamp_ratio(numer: torch.Tensor, denom: torch.Tensor) -> torch.Tensor:
    """``clamp(numer / denom, 0, 1)`` that is 0 where ``denom <= 0`` instead of NaN/Inf."""
    positive = denom > 0
    ratio = (numer / torch.where(positive, denom, 1.0)).clamp_(0.0, 1.0)
    return torch.where(positive, ratio, 0.0)


def _check_pairs(points: torch.Tensor, triangles: torch.Tensor) -> None:
    check_tensor("points", points, (None, 3))
    check_tensor("triangles", triangles, (points.shape[0], 3, 3))
    if points.dtype != triangles.dtype:
        raise InputError(
            f"points ({points.dtype}) and triangles ({triangles.dtype}) must share a dtype"
        )


def closest_point_on_segments(
    points: torch.Tensor, seg_a: torch.Tensor, seg_b: torch.Tensor
) -> torch.Tensor:
    """Closest point on segment ``[seg_a, seg_b]`` to each point, pairwise.

    A zero-length segment is its end point (no division by zero).

    Args:
        points: ``[P, 3]``.
        seg_a: ``[P, 3]`` segment starts.
        seg_b: ``[P, 3]`` segment ends.

    Returns:
        ``[P, 3]`` closest points, same dtype as the inputs.
    """
    direction = seg_b - seg_a
    u = _clamp_ratio((points - seg_a).mul(direction).sum(-1), direction.square().sum(-1))
    return seg_a + u.unsqueeze(-1) * direction


def _vertices(triangles: torch.Tensor) -> tuple[Vec, Vec, Vec]:
    """``[P, 3, 3]`` -> the three vertices as structure-of-arrays vectors."""
    comps = triangles.permute(1, 2, 0).contiguous()  # [vertex, xyz, P]
    return tuple(tuple(vertex.unbind(0)) for vertex in comps.unbind(0))  # type: ignore[return-value]


def _eberly(p: Vec, v0: Vec, v1: Vec, v2: Vec):
    """Eberly's quantities for each pair: region code, the dot products, the degenerate mask."""
    e0, e1, diff = _sub(v1, v0), _sub(v2, v0), _sub(v0, p)
    a, b, c = _dot(e0, e0), _dot(e0, e1), _dot(e1, e1)
    d, e = _dot(e0, diff), _dot(e1, diff)
    normal = _cross(e0, e1)
    det = _dot(normal, normal)
    s = _dot(normal, _cross(e1, diff))
    t = _dot(normal, _cross(diff, e0))

    eps = torch.finfo(a.dtype).eps * _DEGENERATE_EPS_FACTOR
    degenerate = det <= (eps * eps) * a * c

    inside = s + t <= det
    region = torch.where(
        inside,
        torch.where(s < 0, torch.where(t < 0, 4, 3), torch.where(t < 0, 5, 0)),
        torch.where(s < 0, 2, torch.where(t < 0, 6, 1)),
    )
    return region, (a, b, c, d, e, det, s, t), degenerate, (e0, e1, diff)


def triangle_regions(points: torch.Tensor, triangles: torch.Tensor) -> torch.Tensor:
    """Eberly's region (0-6) of each point relative to its triangle; -1 for degenerate ones.

    Args:
        points: ``[P, 3]``.
        triangles: ``[P, 3, 3]``, vertex ``j`` of pair ``i`` is ``triangles[i, j]``.

    Returns:
        ``[P]`` int64 region codes as drawn in the module docstring.
    """
    _check_pairs(points, triangles)
    region, _, degenerate, _ = _eberly(_soa(points), *_vertices(triangles))
    return torch.where(degenerate, -1, region)


def closest_point_on_triangles(
    points: torch.Tensor, triangles: torch.Tensor, *, validate: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """Closest point of each triangle to its point, pairwise, with Eberly's region method.

    Works in float32 and float64 (the inputs' dtype) on any device, with no Python loop over
    pairs. Degenerate triangles (repeated or collinear vertices) give the closest point of the
    segment or point they collapse to; the result is never NaN or Inf for finite input (float32
    coordinates beyond :data:`FLOAT32_SAFE_COORDINATE` are computed in float64 when
    ``validate``).

    Args:
        points: ``[P, 3]`` query points (m).
        triangles: ``[P, 3, 3]`` triangle ``i`` has vertices ``triangles[i, 0..2]`` (m).
        validate: check shapes, dtypes and finiteness first (one reduction over the input).

    Returns:
        ``closest``: ``[P, 3]`` closest points (m); ``sq_dist``: ``[P]`` squared distances (m^2).

    Raises:
        InputError: on wrong shapes, mixed or integer dtypes, or NaN/Inf in the input.
    """
    if validate:
        _check_pairs(points, triangles)
        if points.dtype == torch.float32 and points.shape[0]:
            largest = torch.maximum(points.abs().max(), triangles.abs().max())
            if float(largest) > FLOAT32_SAFE_COORDINATE:  # |N|^2 ~ edge^4 would overflow
                closest, sq_dist = closest_point_on_triangles(
                    points.double(), triangles.double(), validate=False
                )
                return closest.float(), sq_dist.float()
    if points.shape[0] == 0:
        return points.clone(), points.new_zeros(0)

    p = _soa(points)
    v0, v1, v2 = _vertices(triangles)
    region, (a, b, c, d, e, det, s, t), degenerate, (e0, e1, diff) = _eberly(p, v0, v1, v2)

    # Interior (region 0): the projection itself.
    safe_det = torch.where(degenerate, 1.0, det)
    s_in, t_in = s / safe_det, t / safe_det
    # The three edges, as Eberly's regions 1-6 use them.
    s_01 = _clamp_ratio(-d, a)  # edge v0-v1 (t = 0)
    t_02 = _clamp_ratio(-e, c)  # edge v0-v2 (s = 0)
    s_12 = _clamp_ratio(c + e - b - d, a - 2 * b + c)  # edge v1-v2 (s + t = 1)

    # Vertex regions choose an edge by the gradient's sign at the vertex.
    use_12_in_2 = c + e > b + d
    use_12_in_6 = a + d > b + e
    use_01_in_4 = d < 0
    on_12 = (region == 1) | ((region == 2) & use_12_in_2) | ((region == 6) & use_12_in_6)
    on_01 = (region == 5) | ((region == 4) & use_01_in_4) | ((region == 6) & ~use_12_in_6)
    # Everything else outside the interior (3, 4 with d >= 0, 2 without edge 12) is on edge 02.
    interior = region == 0
    s_fin = torch.where(interior, s_in, torch.where(on_12, s_12, torch.where(on_01, s_01, 0.0)))
    t_fin = torch.where(
        interior, t_in, torch.where(on_12, 1.0 - s_12, torch.where(on_01, 0.0, t_02))
    )
    offset = torch.stack([s_fin * e0[k] + t_fin * e1[k] for k in range(3)], dim=1)  # closest - v0
    closest = triangles[:, 0] + offset
    delta = torch.stack([diff[k] for k in range(3)], dim=1) + offset  # closest - point

    if bool(degenerate.any()):
        on_edges = _closest_on_edges(points, triangles)
        mask = degenerate.unsqueeze(-1)
        closest = torch.where(mask, on_edges, closest)
        delta = torch.where(mask, on_edges - points, delta)
    return closest, delta.square().sum(-1)


def _closest_on_edges(points: torch.Tensor, triangles: torch.Tensor) -> torch.Tensor:
    """Closest point over the three edges of each (degenerate) triangle, ``[P, 3]``."""
    v0, v1, v2 = triangles.unbind(dim=-2)
    candidates = torch.stack(
        [
            closest_point_on_segments(points, v0, v1),
            closest_point_on_segments(points, v0, v2),
            closest_point_on_segments(points, v1, v2),
        ],
        dim=1,
    )  # [P, 3 edges, 3]
    sq = (candidates - points.unsqueeze(1)).square().sum(-1)
    best = sq.argmin(dim=1)
    return candidates[torch.arange(points.shape[0], device=points.device), best]
