"""segment_triangle_crossings: hand cases, edges, degenerate triangles, a brute-force reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from granular_pyg.geometry import segment_triangle_crossings

TRI = torch.tensor([[(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)]], dtype=torch.float64)


def _cross(start, end, tri=TRI):
    s = torch.tensor([start], dtype=torch.float64)
    e = torch.tensor([end], dtype=torch.float64)
    return segment_triangle_crossings(s, e, tri)


def test_a_move_through_the_middle_crosses_halfway_with_the_normal_towards_the_start():
    hit = _cross((0.2, 0.2, 1.0), (0.2, 0.2, -3.0))
    assert hit.crosses.tolist() == [True]
    assert hit.fraction.item() == pytest.approx(0.25)
    assert hit.normal[0].tolist() == [0.0, 0.0, 1.0]
    assert hit.start_distance.item() == 1.0 and hit.end_depth.item() == 3.0
    from_below = _cross((0.2, 0.2, -1.0), (0.2, 0.2, 1.0))
    assert from_below.crosses.item() and from_below.normal[0].tolist() == [0.0, 0.0, -1.0]


@pytest.mark.parametrize(
    ("name", "start", "end", "crosses"),
    [
        ("ends on the plane", (0.2, 0.2, 1.0), (0.2, 0.2, 0.0), True),
        ("through an edge", (0.5, -1.0, 1.0), (0.5, 1.0, -1.0), True),  # at (0.5, 0, 0)
        ("through a vertex", (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), True),
        ("stops short", (0.2, 0.2, 1.0), (0.2, 0.2, 0.1), False),
        ("beside the triangle", (0.8, 0.8, 1.0), (0.8, 0.8, -1.0), False),
        ("parallel, above", (0.1, 0.1, 0.5), (0.6, 0.1, 0.5), False),
        ("in the plane", (0.1, 0.1, 0.0), (0.3, 0.1, 0.0), False),
        ("starts on the plane", (0.2, 0.2, 0.0), (0.2, 0.2, -1.0), False),
        ("zero length", (0.2, 0.2, 1.0), (0.2, 0.2, 1.0), False),
    ],
)
def test_hand_cases(name, start, end, crosses):
    assert _cross(start, end).crosses.item() is crosses, name


def test_a_move_that_stops_in_the_skin_crosses_at_its_end():
    """With a skin, a move that ends on its start's side closer than the skin to the plane,
    over the triangle, counts (the wall guard's margin against round-off)."""
    start = torch.tensor([[0.2, 0.2, 1.0], [0.2, 0.2, 1.0], [0.9, 0.9, 1.0], [0.2, 0.2, 1.0]])
    end = torch.tensor([[0.3, 0.2, 0.05], [0.3, 0.2, 0.2], [0.9, 0.9, 0.05], [0.2, 0.2, -1.0]])
    hit = segment_triangle_crossings(start.double(), end.double(), TRI, skin=0.1)
    assert hit.crosses.tolist() == [True, False, False, True]  # in, above, beside, through
    assert hit.fraction[0].item() == 1.0 and hit.fraction[3].item() == 0.5
    assert hit.end_depth[0].item() == pytest.approx(-0.05)
    plain = segment_triangle_crossings(start.double(), end.double(), TRI)
    assert plain.crosses.tolist() == [False, False, False, True]


def test_degenerate_triangles_are_never_crossed():
    flat = torch.tensor(
        [[(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0)], [(0.0, 0.0, 0.0)] * 3],
        dtype=torch.float64,
    )
    start = torch.tensor([(0.5, 0.0, 1.0)] * 2, dtype=torch.float64)
    hit = segment_triangle_crossings(start, -start, flat)
    assert not hit.crosses.any() and torch.isfinite(hit.normal).all()


def test_a_move_through_the_shared_edge_of_two_triangles_crosses_at_least_one():
    quad = torch.tensor(
        [
            [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0)],
            [(0.0, 0.0, 0.0), (1.0, 1.0, 0.0), (0.0, 1.0, 0.0)],
        ],
        dtype=torch.float64,
    )
    t = torch.rand(101, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    on_diagonal = torch.stack([t, t, torch.zeros_like(t)], 1).repeat_interleave(2, 0)
    up = torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64)
    hit = segment_triangle_crossings(on_diagonal + up, on_diagonal - up, quad.repeat(101, 1, 1))
    assert hit.crosses.view(101, 2).any(1).all()


def _reference(start, end, tri) -> bool:
    """Sign change of the plane distance, then the crossing point inside by signed areas."""
    v0, v1, v2 = tri
    n = np.cross(v1 - v0, v2 - v0)
    a, b = float((start - v0) @ n), float((end - v0) @ n)
    if a == 0.0 or a * b > 0.0:
        return False
    q = start + a / (a - b) * (end - start)
    return all(float(np.cross(y - x, q - x) @ n) >= 0.0 for x, y in ((v0, v1), (v1, v2), (v2, v0)))


def test_random_moves_agree_with_the_brute_force_reference():
    rng = np.random.default_rng(7)
    k = 4000
    tris = rng.normal(size=(k, 3, 3))
    start = rng.normal(size=(k, 3))
    end = start + 2.0 * rng.normal(size=(k, 3))
    hit = segment_triangle_crossings(
        torch.from_numpy(start), torch.from_numpy(end), torch.from_numpy(tris)
    )
    expected = np.array([_reference(s, e, t) for s, e, t in zip(start, end, tris, strict=True)])
    assert 100 < expected.sum() < k  # enough crossings to mean something
    assert (hit.crosses.numpy() == expected).all()
    f = hit.fraction.numpy()[expected]
    assert ((f >= 0) & (f <= 1)).all()
    crossing_point = start + hit.fraction.numpy()[:, None] * (end - start)
    plane_dist = np.einsum("kj,kj->k", crossing_point - tris[:, 0], hit.normal.numpy())
    np.testing.assert_allclose(plane_dist[expected], 0.0, atol=1e-9)
