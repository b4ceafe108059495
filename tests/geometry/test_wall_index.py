"""WallIndex returns exactly the brute-force pair set, with work that follows the near pairs."""

from __future__ import annotations

import math

import pytest
import torch
import trimesh

from granular_pyg.errors import InputError
from granular_pyg.geometry import (
    WallIndex,
    closest_point_on_triangles,
    dense_wall_pairs,
    pose_about_axis,
)
from granular_pyg.geometry.wall_index import _Bounds


def _pair_set(point_idx, tri_idx) -> set[tuple[int, int]]:
    return set(zip(point_idx.tolist(), tri_idx.tolist(), strict=True))


def _random_scene(seed: int, num_points=3000, dtype=torch.float64):
    """A subdivided icosphere and a box (hundreds of triangles) with points around them."""
    g = torch.Generator().manual_seed(seed)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.3)  # 320 triangles
    box = trimesh.creation.box(extents=(0.4, 0.2, 0.6))
    box.apply_translation((0.5, 0.1, -0.2))
    mesh = trimesh.util.concatenate([sphere, box])
    vertices = torch.tensor(mesh.vertices, dtype=dtype)
    vertices += 0.01 * torch.randn(vertices.shape, generator=g, dtype=dtype)  # irregular
    faces = torch.tensor(mesh.faces, dtype=torch.int64)
    points = (torch.rand(num_points, 3, generator=g, dtype=dtype) - 0.5) * 1.6
    return vertices, faces, points


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("radius", [0.003, 0.02, 0.07, 0.25])
def test_query_equals_dense_brute_force(seed, radius):
    vertices, faces, points = _random_scene(seed)
    index = WallIndex(vertices, faces)
    found = index.pairs(points, radius)
    dense = dense_wall_pairs(points, vertices[faces], radius)
    assert _pair_set(found.point_idx, found.tri_idx) == _pair_set(dense.point_idx, dense.tri_idx)
    assert len(found.point_idx) > 0
    # Same pairs in the same (sorted) order, so the closest points line up too.
    torch.testing.assert_close(found.closest, dense.closest)
    torch.testing.assert_close(found.sq_dist, dense.sq_dist)
    assert (found.sq_dist < radius**2).all()


@pytest.mark.parametrize("cell_size", [0.37, 1.0, 2.5])
def test_cell_size_changes_work_but_not_the_answer(cell_size):
    vertices, faces, points = _random_scene(3)
    dense = dense_wall_pairs(points, vertices[faces], 0.05)
    pi, ti = WallIndex(vertices, faces, cell_size=cell_size).query(points, 0.05)
    assert _pair_set(pi, ti) == _pair_set(dense.point_idx, dense.tri_idx)


def test_tiny_cell_cap_still_gives_exact_pairs():
    vertices, faces, points = _random_scene(4)
    dense = dense_wall_pairs(points, vertices[faces], 0.05)
    pi, ti = WallIndex(vertices, faces, max_cells=1000).query(points, 0.05)
    assert _pair_set(pi, ti) == _pair_set(dense.point_idx, dense.tri_idx)


@pytest.mark.parametrize("angle", [0.3, 1.7, math.pi])
def test_rotated_mesh_is_queried_in_its_frame_without_rebuilding(angle):
    vertices, faces, points = _random_scene(5)
    index = WallIndex(vertices, faces)
    rotation, translation = pose_about_axis((0.2, 1.0, -0.3), angle, origin=(0.1, 0.0, 0.2))
    found = index.pairs(points, 0.05, rotation, translation)
    moved = vertices @ rotation.T + translation
    dense = dense_wall_pairs(points, moved[faces], 0.05)
    assert _pair_set(found.point_idx, found.tri_idx) == _pair_set(dense.point_idx, dense.tri_idx)
    torch.testing.assert_close(found.closest, dense.closest)  # world frame
    index.query(points, 0.05)  # and once unrotated
    assert len(index._grids) == 1  # one grid for the radius, reused for every pose


def test_float32_points_on_a_float64_mesh():
    vertices, faces, points = _random_scene(6)
    found = WallIndex(vertices, faces).pairs(points.float(), 0.05)
    dense = dense_wall_pairs(points.float(), vertices[faces].float(), 0.05)
    assert found.closest.dtype == torch.float32
    assert _pair_set(found.point_idx, found.tri_idx) == _pair_set(dense.point_idx, dense.tri_idx)


def test_work_follows_near_pairs_not_points_times_triangles():
    vertices, faces, points = _random_scene(7, num_points=2000)
    radius = 0.03
    index = WallIndex(vertices, faces)
    near = len(index.query(points, radius)[0])
    work = len(index.candidates(points, radius)[0])
    assert work <= 12 * near + len(points)
    assert work < 0.02 * len(points) * len(faces)

    # 20,000 far-away triangles add no work for these points.
    far = trimesh.creation.icosphere(subdivisions=5, radius=0.5)  # 20,480 triangles
    far.apply_translation((10.0, 0.0, 0.0))
    big_vertices = torch.cat([vertices, torch.tensor(far.vertices)])
    big_faces = torch.cat([faces, torch.tensor(far.faces) + len(vertices)])
    big = WallIndex(big_vertices, big_faces)
    _, big_tri = big.candidates(points, radius)
    assert (big_tri < len(faces)).all()  # no far triangle is ever a candidate
    assert len(big_tri) <= 1.5 * work  # (the grid's origin shifts, so not exactly equal)
    assert len(big.query(points, radius)[0]) == near


@pytest.mark.parametrize("radius", [1e-6, 1e-4])
def test_a_radius_far_below_the_triangles_keeps_the_grid_small_and_exact(radius):
    """A tiny query radius (the training noise's wall check) gets cells of at least an eighth
    of the median edge, not millions of radius-sized ones, and the same pairs as brute force."""
    vertices, faces, points = _random_scene(11, num_points=500)
    points = torch.cat([points, vertices[:200] + 0.5 * radius])  # some points within reach
    index = WallIndex(vertices, faces)
    found = index.pairs(points, radius)
    dense = dense_wall_pairs(points, vertices[faces], radius)
    assert _pair_set(found.point_idx, found.tri_idx) == _pair_set(dense.point_idx, dense.tri_idx)
    assert len(found.point_idx) > 0
    grid = index._grid(radius)
    assert grid.cell_size == pytest.approx(index.min_cell) and math.prod(grid.dims) < 1_000_000
    assert index._grid(0.05).cell_size == 0.05  # a radius above the floor keeps its own cells


def test_points_far_from_every_wall_and_empty_queries():
    vertices, faces, _ = _random_scene(8)
    index = WallIndex(vertices, faces)
    pi, ti = index.query(torch.full((5, 3), 100.0, dtype=torch.float64), 0.1)
    assert pi.shape == ti.shape == (0,)
    found = index.pairs(torch.zeros(0, 3, dtype=torch.float64), 0.1)
    assert found.closest.shape == (0, 3)


def test_degenerate_triangles_in_the_mesh_are_handled():
    vertices = torch.tensor([(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0)], dtype=torch.float64)
    faces = torch.tensor([(0, 1, 2), (0, 0, 0), (0, 1, 3)])  # collinear, a point, a real one
    points = torch.tensor([(1.5, 0.01, 0.0), (0.0, 0.0, 0.02)], dtype=torch.float64)
    found = WallIndex(vertices, faces).pairs(points, 0.05)
    assert _pair_set(found.point_idx, found.tri_idx) == {(0, 0), (1, 0), (1, 1), (1, 2)}
    assert torch.isfinite(found.closest).all()


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_distance_bounds_never_exceed_the_exact_distance(dtype):
    """The cheap plane and bounding-sphere bounds that skip exact tests stay below the true
    distance (within their stated slack), thin and degenerate triangles included."""
    vertices, faces, points = _random_scene(9, num_points=400)
    thin = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 1e-9, 0], [0, 0, 0]], dtype=torch.float64)
    tris = torch.cat([vertices[faces], thin[:3][None], thin[[0, 3, 1]][None]])
    bounds = _Bounds.of(tris, dtype)
    p_idx = torch.arange(len(points)).repeat_interleave(len(tris))
    t_idx = torch.arange(len(tris)).repeat(len(points))
    _, sq = closest_point_on_triangles(points[p_idx], tris[t_idx])
    lower = bounds.lower(points[p_idx].to(dtype), t_idx).double()
    assert (lower <= sq.sqrt() + bounds.slack).all()
    assert (lower > 0.05).float().mean() > 0.5  # and they do rule out most far pairs


def test_grid_lists_exactly_the_cells_within_reach_of_each_triangle():
    """The grid against brute force over every cell: (cell, triangle) is listed iff the cell
    meets the triangle's bounding box grown by the radius and its centre lies within radius +
    half the cell diagonal of the triangle."""
    vertices, faces, _ = _random_scene(10)
    radius = 0.04
    index = WallIndex(vertices, faces)
    grid = index._grid(radius)
    nx, ny, nz = grid.dims
    ijk = torch.cartesian_prod(torch.arange(nx), torch.arange(ny), torch.arange(nz))
    centre = grid.origin + (ijk.double() + 0.5) * grid.cell_size
    reach = radius + 0.5 * math.sqrt(3.0) * grid.cell_size
    expected = set()
    for t in range(len(faces)):
        tri = vertices[faces[t]]
        lo = torch.floor((tri.min(0).values - radius - grid.origin) / grid.cell_size).long()
        hi = torch.floor((tri.max(0).values + radius - grid.origin) / grid.cell_size).long()
        _, sq = closest_point_on_triangles(centre, tri.expand(len(centre), 3, 3))
        in_box = ((ijk >= lo) & (ijk <= hi)).all(dim=1)
        cells = ijk[in_box & (sq <= reach**2)]
        ids = cells[:, 0] + nx * (cells[:, 1] + ny * cells[:, 2])
        expected |= {(int(c), t) for c in ids}
    counts = grid.cell_start[1:] - grid.cell_start[:-1]
    cell_of_entry = torch.repeat_interleave(torch.arange(len(counts)), counts)
    assert set(zip(cell_of_entry.tolist(), grid.cell_tris.tolist(), strict=True)) == expected


@pytest.mark.parametrize(
    ("vertices", "faces", "message"),
    [
        (torch.zeros(3, 2), torch.zeros(1, 3, dtype=torch.long), "vertices: expected shape"),
        (torch.zeros(3, 3), torch.zeros(0, 3, dtype=torch.long), "no triangles"),
        (torch.zeros(3, 3), torch.tensor([[0, 1, 3]]), r"indices must lie in \[0, 2\]"),
        (torch.zeros(3, 3), torch.zeros(1, 3), "integer"),
        (torch.full((3, 3), float("nan")), torch.tensor([[0, 1, 2]]), "NaN or Inf"),
    ],
)
def test_bad_meshes_raise_one_clear_error(vertices, faces, message):
    with pytest.raises(InputError, match=message):
        WallIndex(vertices, faces)


@pytest.mark.parametrize("radius", [0.0, -1.0, float("nan"), float("inf"), "x"])
def test_bad_radius_is_rejected(radius):
    index = WallIndex(torch.eye(3), torch.tensor([[0, 1, 2]]))
    with pytest.raises(InputError, match="radius"):
        index.query(torch.zeros(1, 3), radius)
