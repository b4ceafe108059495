"""closest_point_on_triangles: Eberly's seven regions, degenerate triangles, references."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from granular_pyg.errors import InputError
from granular_pyg.geometry import (
    closest_point_on_segments,
    closest_point_on_triangles,
    triangle_regions,
)
from tests.geometry.reference import closest_on_triangle

RIGHT = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
OBTUSE_AT_V0 = [(0, 0, 0), (1, 0, 0), (-1, 1, 0)]
OBTUSE_AT_V1 = [(0, 0, 0), (1, 0, 0), (1.8, 0.2, 0)]
OBTUSE_AT_V2 = [(0, 0, 0), (2, 0, 0), (1, 0.2, 0)]
U = 0.184 / 1.04  # projection parameter of the obtuse-at-v2 cases, worked out by hand

# (name, triangle, point, Eberly region, expected closest point, expected squared distance)
HAND_CASES = [
    ("interior", RIGHT, (0.25, 0.25, 2), 0, (0.25, 0.25, 0), 4.0),
    ("edge12", RIGHT, (1, 1, 0.5), 1, (0.5, 0.5, 0), 0.75),
    ("beyond v2 -> v2", RIGHT, (-0.5, 2, 0), 2, (0, 1, 0), 1.25),
    ("beyond v2 -> edge02", OBTUSE_AT_V2, (0.1, 0.42, 0), 2, (U, 0.2 * U, 0), None),
    ("beyond v2 -> edge12", OBTUSE_AT_V2, (1.9, 0.42, 0), 2, (2 - U, 0.2 * U, 0), None),
    ("edge02", RIGHT, (-1, 0.5, 0), 3, (0, 0.5, 0), 1.0),
    ("beyond v0 -> v0", RIGHT, (-1, -1, 0), 4, (0, 0, 0), 2.0),
    ("beyond v0 -> edge01", OBTUSE_AT_V0, (0.1, -0.5, 0), 4, (0.1, 0, 0), 0.25),
    ("edge01", RIGHT, (0.5, -1, 0), 5, (0.5, 0, 0), 1.0),
    ("beyond v1 -> v1", RIGHT, (2, -0.5, 0), 6, (1, 0, 0), 1.25),
    ("beyond v1 -> edge12", OBTUSE_AT_V1, (1.46, -0.14, 0), 6, (1.4, 0.1, 0), 0.0612),
]


def _pair(triangle, point, dtype=torch.float64):
    return (
        torch.tensor([point], dtype=dtype),
        torch.tensor([triangle], dtype=dtype),
    )


@pytest.mark.parametrize(
    ("triangle", "point", "region", "closest", "sq"),
    [case[1:] for case in HAND_CASES],
    ids=[case[0] for case in HAND_CASES],
)
def test_each_region_by_hand(triangle, point, region, closest, sq):
    p, tri = _pair(triangle, point)
    assert triangle_regions(p, tri).item() == region
    got, got_sq = closest_point_on_triangles(p, tri)
    torch.testing.assert_close(got[0], torch.tensor(closest, dtype=torch.float64))
    want_sq = sq if sq is not None else float(((got[0] - p[0]) ** 2).sum())
    assert got_sq.item() == pytest.approx(want_sq, rel=1e-12, abs=1e-15)
    # The same answer as the brute-force reference.
    ref, ref_sq = closest_on_triangle(np.array(point, float), np.array(triangle, float))
    np.testing.assert_allclose(got[0].numpy(), ref, atol=1e-12)
    assert got_sq.item() == pytest.approx(ref_sq, rel=1e-12)


def test_all_seven_regions_are_covered_by_hand_cases():
    assert {case[3] for case in HAND_CASES} == set(range(7))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_points_exactly_on_vertices_and_edges_are_their_own_closest_point(dtype):
    tri = torch.tensor(RIGHT, dtype=dtype)
    on = torch.tensor(
        [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0.5, 0, 0), (0, 0.5, 0), (0.5, 0.5, 0), (0.25, 0.5, 0)],
        dtype=dtype,
    )
    closest, sq = closest_point_on_triangles(on, tri.expand(len(on), 3, 3))
    assert torch.equal(closest, on)
    assert torch.equal(sq, torch.zeros_like(sq))


DEGENERATE_CASES = [
    # (triangle, point, expected closest)
    ([(1, 2, 3), (1, 2, 3), (1, 2, 3)], (0, 0, 0), (1, 2, 3)),  # a point
    ([(0, 0, 0), (0, 0, 0), (0, 0, 1)], (1, 0, 0.5), (0, 0, 0.5)),  # repeated vertex
    ([(0, 0, 1), (0, 0, 0), (0, 0, 0)], (1, 0, 2), (0, 0, 1)),  # repeated, other order
    ([(0, 0, 0), (1, 0, 0), (2, 0, 0)], (1.5, 1, 0), (1.5, 0, 0)),  # collinear
    ([(0, 0, 0), (2, 0, 0), (1, 0, 0)], (3, 0, 1), (2, 0, 0)),  # collinear, middle last
    ([(0, 0, 0), (1, 0, 0), (2, 0, 0)], (-1, 0, 0), (0, 0, 0)),  # collinear, before start
]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("triangle", "point", "closest"), DEGENERATE_CASES)
def test_degenerate_triangle_gives_closest_point_of_segment_or_point(
    dtype, triangle, point, closest
):
    p, tri = _pair(triangle, point, dtype)
    assert triangle_regions(p, tri).item() == -1
    got, sq = closest_point_on_triangles(p, tri)
    torch.testing.assert_close(got[0], torch.tensor(closest, dtype=dtype))
    torch.testing.assert_close(sq[0], ((got[0] - p[0]) ** 2).sum())


def test_segment_of_zero_length_is_its_end_point():
    p = torch.tensor([[1.0, 1.0, 1.0]])
    a = torch.tensor([[0.0, 0.0, 0.0]])
    assert torch.equal(closest_point_on_segments(p, a, a), a)


def test_empty_input_gives_empty_output():
    closest, sq = closest_point_on_triangles(torch.zeros(0, 3), torch.zeros(0, 3, 3))
    assert closest.shape == (0, 3)
    assert sq.shape == (0,)


@pytest.mark.parametrize(
    ("points", "triangles", "message"),
    [
        (torch.zeros(2, 2), torch.zeros(2, 3, 3), "points: expected shape"),
        (torch.zeros(2, 3), torch.zeros(3, 3, 3), "triangles: expected shape"),
        (torch.zeros(2, 3), torch.zeros(2, 3, 3, dtype=torch.float64), "share a dtype"),
        (torch.zeros(2, 3, dtype=torch.int64), torch.zeros(2, 3, 3), "float32 or float64"),
        (torch.tensor([[0.0, float("nan"), 0.0]]), torch.zeros(1, 3, 3), "NaN or Inf"),
        (torch.zeros(1, 3), torch.full((1, 3, 3), float("inf")), "NaN or Inf"),
    ],
)
def test_bad_input_raises_one_clear_error(points, triangles, message):
    with pytest.raises(InputError, match=message):
        closest_point_on_triangles(points, triangles)


# -- properties against references ------------------------------------------------------------

coords = arrays(
    np.float64,
    (64, 4, 3),
    elements=st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False),
)


def _min_angle_deg(tri: np.ndarray) -> float:
    angles = []
    for i in range(3):
        a, b, c = tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]
        u, v = b - a, c - a
        nu, nv = np.linalg.norm(u), np.linalg.norm(v)
        if nu == 0 or nv == 0:
            return 0.0
        angles.append(np.degrees(np.arccos(np.clip(u @ v / (nu * nv), -1, 1))))
    return min(angles)


def _shortest_edge(tri: np.ndarray) -> float:
    return min(float(np.linalg.norm(tri[i] - tri[(i + 1) % 3])) for i in range(3))


@settings(max_examples=60, deadline=None)
@given(coords)
def test_matches_brute_force_reference_in_float64(data):
    points, tris = torch.from_numpy(data[:, 0].copy()), torch.from_numpy(data[:, 1:].copy())
    closest, sq = closest_point_on_triangles(points, tris)
    assert torch.isfinite(closest).all() and torch.isfinite(sq).all()
    for i in range(len(data)):
        _, ref_sq = closest_on_triangle(data[i, 0], data[i, 1:])
        assert sq[i].item() == pytest.approx(ref_sq, rel=1e-9, abs=1e-12)
        # The returned point lies on the triangle and realises the distance.
        _, on_sq = closest_on_triangle(closest[i].numpy(), data[i, 1:])
        assert on_sq <= 1e-20
        assert float(((closest[i] - points[i]) ** 2).sum()) == pytest.approx(sq[i].item())


@settings(max_examples=20, deadline=None)
@given(coords)
def test_matches_trimesh_proximity(data):
    """Against trimesh on triangles it resolves: its fixed tolerances (1e-8 and below) misplace
    the closest point of triangles a few micrometres across, which the float64 brute-force test
    above covers at every scale."""
    keep = [
        i
        for i in range(len(data))
        if _min_angle_deg(data[i, 1:]) > 0.256 and _shortest_edge(data[i, 1:]) > 1e-3
    ]
    if not keep:
        return
    data = data[keep]
    _, sq = closest_point_on_triangles(
        torch.from_numpy(data[:, 0].copy()), torch.from_numpy(data[:, 1:].copy())
    )
    for i in range(len(data)):
        mesh = trimesh.Trimesh(vertices=data[i, 1:], faces=[[0, 1, 2]], process=False)
        _, dist, _ = trimesh.proximity.closest_point(mesh, data[i, :1])
        assert np.sqrt(sq[i].item()) == pytest.approx(dist[0], rel=1e-7, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(coords)
def test_float32_precision_holds_for_triangles_above_the_liggghts_angle_limit(data):
    """float32 keeps the distance within 2e-6 m of float64 on metre-scale scenes whose
    triangles pass LIGGGHTS's 0.256 degree angle check."""
    keep = [i for i in range(len(data)) if _min_angle_deg(data[i, 1:]) > 0.256]
    if not keep:
        return
    data = torch.from_numpy(data[keep].copy())
    _, sq64 = closest_point_on_triangles(data[:, 0], data[:, 1:])
    _, sq32 = closest_point_on_triangles(data[:, 0].float(), data[:, 1:].float())
    torch.testing.assert_close(sq32.double().sqrt(), sq64.sqrt(), rtol=0, atol=2e-6)


@settings(max_examples=40, deadline=None)
@given(
    arrays(np.float64, (32, 3, 3), elements=st.floats(-1, 1, allow_subnormal=False)),
    arrays(np.float64, (32, 2), elements=st.floats(-2, 2, allow_subnormal=False)),
    st.sampled_from([torch.float32, torch.float64]),
)
def test_collinear_triangles_are_finite_and_match_the_segment_reference(base, mix, dtype):
    # v2 = v0 + lambda (v1 - v0) and a repeated vertex in some rows: zero area by construction.
    tri = base.copy()
    tri[:, 2] = tri[:, 0] + mix[:, :1] * (tri[:, 1] - tri[:, 0])
    tri[::4, 1] = tri[::4, 0]
    points = base[:, 2] + mix[:, 1:] * 0.5
    closest, sq = closest_point_on_triangles(
        torch.from_numpy(points).to(dtype), torch.from_numpy(tri).to(dtype)
    )
    assert torch.isfinite(closest).all() and torch.isfinite(sq).all()
    for i in range(len(tri)):
        _, ref_sq = closest_on_triangle(points[i], tri[i])
        tol = 1e-9 if dtype == torch.float64 else 1e-5
        assert np.sqrt(sq[i].item()) == pytest.approx(np.sqrt(ref_sq), abs=tol)


def test_sliver_triangles_in_float32_stay_finite():
    # Angles down to 1e-30 rad, far below any degeneracy threshold, and huge aspect ratios.
    eps = torch.logspace(-30, -1, 32, dtype=torch.float64)
    tris = torch.zeros(32, 3, 3, dtype=torch.float64)
    tris[:, 1, 0] = 1.0
    tris[:, 2, 0] = 0.5
    tris[:, 2, 1] = eps
    points = torch.tensor([0.3, 0.7, 0.2], dtype=torch.float64).expand(32, 3)
    closest, sq = closest_point_on_triangles(points.float(), tris.float())
    assert torch.isfinite(closest).all() and torch.isfinite(sq).all()
    _, sq64 = closest_point_on_triangles(points, tris)
    torch.testing.assert_close(sq.double(), sq64, rtol=1e-5, atol=1e-7)


def test_float32_triangles_with_huge_edges_give_finite_closest_points():
    tri = torch.tensor([[[0.0, 0.0, 0.0], [1e10, 0.0, 0.0], [0.0, 1e10, 0.0]]])
    point = torch.tensor([[2e9, 3e9, 5e9]])
    closest, sq = closest_point_on_triangles(point, tri)
    ref, ref_sq = closest_point_on_triangles(point.double(), tri.double())
    assert closest.dtype == torch.float32 and bool(torch.isfinite(closest).all())
    torch.testing.assert_close(closest.double(), ref, rtol=1e-6, atol=0.0)
    torch.testing.assert_close(sq.double(), ref_sq, rtol=1e-6, atol=0.0)
