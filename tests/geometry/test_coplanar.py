"""coplanar_redundant: one wall contact per plane, whatever the triangulation."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from granular_pyg.errors import InputError
from granular_pyg.geometry import closest_point_on_triangles, coplanar_redundant, triangle_normals


def _grid_square(m: int) -> np.ndarray:
    """``[2 m^2, 3, 3]``: the unit square z = 0 cut into an m x m grid of triangle pairs."""
    tris = []
    for i, j in itertools.product(range(m), range(m)):
        a, b = np.array([i, j, 0.0]) / m, np.array([i + 1, j, 0.0]) / m
        c, d = np.array([i + 1, j + 1, 0.0]) / m, np.array([i, j + 1, 0.0]) / m
        tris += [[a, b, c], [a, c, d]]
    return np.array(tris)


def _cube(m: int) -> np.ndarray:
    """``[12 m^2, 3, 3]``: the unit cube's six faces, each an m x m grid of triangle pairs."""
    square = _grid_square(m).reshape(-1, 3)
    faces = []
    for axis in range(3):
        for level in (0.0, 1.0):
            pts = np.insert(np.delete(square, 2, axis=1), axis, level, axis=1)
            faces.append(pts.reshape(-1, 3, 3))
    return np.concatenate(faces)


def _contacts(points: np.ndarray, tris: np.ndarray, radius: float):
    """Every (point, triangle) pair closer than ``radius``, by brute force."""
    p = torch.from_numpy(points)
    t = torch.from_numpy(tris)
    pi, ti = torch.meshgrid(torch.arange(len(p)), torch.arange(len(t)), indexing="ij")
    pi, ti = pi.reshape(-1), ti.reshape(-1)
    closest, sq = closest_point_on_triangles(p[pi], t[ti])
    near = sq < radius**2
    return p, pi[near], closest[near], triangle_normals(t)[ti[near]]


def test_a_finely_cut_floor_leaves_one_node_at_the_projection():
    p, idx, closest, normal = _contacts(np.array([[0.3, 0.4, 0.05]]), _grid_square(10), 0.3)
    assert len(idx) > 20  # the paper's one node per triangle
    keep = ~coplanar_redundant(p, idx, closest, normal, 1e-6)
    assert keep.sum() == 1
    torch.testing.assert_close(closest[keep][0], torch.tensor([0.3, 0.4, 0.0], dtype=torch.float64))


@pytest.mark.parametrize("m", [1, 2, 7])
def test_a_cube_gives_one_node_per_face_within_reach_at_any_triangulation(m):
    rng = np.random.default_rng(m)
    points = rng.uniform(0.02, 0.98, (60, 3))
    radius = 0.25
    p, idx, closest, normal = _contacts(points, _cube(m), radius)
    keep = ~coplanar_redundant(p, idx, closest, normal, 1e-6)
    for i, x in enumerate(points):
        # Brute-force reference: inside the cube, each face within reach is met at x's
        # projection on it.
        expected = sorted(
            tuple(np.round(np.where(np.arange(3) == axis, level, x), 9))
            for axis in range(3)
            for level in (0.0, 1.0)
            if abs(x[axis] - level) < radius
        )
        got = sorted(tuple(np.round(c, 9)) for c in closest[keep & (idx == i)].numpy())
        assert got == expected


def test_contacts_of_other_particles_never_merge():
    tris = _grid_square(4)
    points = np.array([[0.3, 0.4, 0.05], [0.31, 0.4, 0.05]])
    p, idx, closest, normal = _contacts(points, tris, 0.2)
    keep = ~coplanar_redundant(p, idx, closest, normal, 1e-6)
    assert torch.bincount(idx[keep]).tolist() == [1, 1]


def test_empty_and_bad_tolerance():
    empty = torch.zeros(0, dtype=torch.int64)
    vec = torch.zeros(0, 3)
    assert coplanar_redundant(torch.zeros(1, 3), empty, vec, vec, 0.0).shape == (0,)
    with pytest.raises(InputError, match="tolerance"):
        coplanar_redundant(torch.zeros(1, 3), empty, vec, vec, -1.0)
