"""radius_graph: both backends return exactly the brute-force edge set, never truncated."""

from __future__ import annotations

import contextlib
import importlib
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch_geometric.data import Data

from granular_pyg.errors import InputError
from granular_pyg.transforms.radius_graph import (
    RadiusGraph,
    _torch_cluster_candidates,
    radius_graph,
)

rg = importlib.import_module("granular_pyg.transforms.radius_graph")

BACKENDS = ("scipy", "torch_cluster")


@contextlib.contextmanager
def _slabs_from(points_per_thread: int):
    """Split the scipy search into slabs from ``points_per_thread`` points per thread on."""
    old, rg.SLAB_POINTS = rg.SLAB_POINTS, points_per_thread
    try:
        yield
    finally:
        rg.SLAB_POINTS = old


@contextlib.contextmanager
def _torch_threads(threads: int):
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def brute_force(pos: torch.Tensor, radius: float) -> torch.Tensor:
    """Every ordered pair ``(j, i)``, ``i != j``, with the exact test of the definition:
    ``(dx*dx + dy*dy) + dz*dz < radius**2`` in ``pos.dtype``, sorted by (target, source)."""
    d = pos[:, None, :] - pos[None, :, :]  # [i, j, 3]: pos[i] - pos[j]
    sq = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
    near = sq < torch.tensor(radius * radius, dtype=pos.dtype)
    near.fill_diagonal_(False)
    target, source = near.nonzero(as_tuple=True)  # row-major: sorted by (target, source)
    return torch.stack([source, target])


def edge_set(edge_index: torch.Tensor) -> set[tuple[int, int]]:
    return set(zip(edge_index[0].tolist(), edge_index[1].tolist(), strict=True))


def assert_matches_cdist(edge_index: torch.Tensor, pos: torch.Tensor, radius: float) -> None:
    """Independent check with ``torch.cdist`` in float64: every pair clearly inside the radius
    is an edge, none clearly outside is (pairs within round-off of the radius may go either way).
    """
    dist = torch.cdist(pos.double(), pos.double(), compute_mode="donot_use_mm_for_euclid_dist")
    got = torch.zeros_like(dist, dtype=torch.bool)
    got[edge_index[1], edge_index[0]] = True
    band = 1e-5 * radius
    inside = dist < radius - band
    inside.fill_diagonal_(False)
    outside = dist > radius + band
    assert not (inside & ~got).any(), "a pair clearly within the radius is missing"
    assert not (outside & got).any(), "a pair clearly beyond the radius is an edge"


# --- tiny exact cases -------------------------------------------------------------------------


@pytest.mark.parametrize("backend", ("auto", *BACKENDS))
@pytest.mark.parametrize("dtype", (torch.float32, torch.float64))
def test_four_points_known_pairs_and_distance_equal_to_radius_excluded(backend, dtype):
    # Distances: |01| = 1, |02| = 2 (= radius: excluded), |03| = 1.5, |12| = sqrt(5),
    # |13| = 2.5, |23| = 2.5. Only 0-1 and 0-3 are strictly closer than 2.
    pos = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 2, 0], [-1.5, 0, 0]], dtype=dtype)
    edge_index = radius_graph(pos, 2.0, backend=backend)
    expected = torch.tensor([[1, 3, 0, 0], [0, 0, 1, 3]])  # (source, target), target-major
    assert edge_index.dtype == torch.int64
    assert torch.equal(edge_index, expected)


@pytest.mark.parametrize("backend", BACKENDS)
def test_coincident_points_are_connected_but_never_to_themselves(backend):
    pos = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    assert torch.equal(radius_graph(pos, 0.1, backend=backend), torch.tensor([[1, 0], [0, 1]]))


@pytest.mark.parametrize("backend", ("auto", *BACKENDS))
@pytest.mark.parametrize("num_nodes", (0, 1))
def test_fewer_than_two_points_give_an_empty_int64_edge_index(backend, num_nodes):
    edge_index = radius_graph(torch.zeros(num_nodes, 3), 1.0, backend=backend)
    assert edge_index.shape == (2, 0)
    assert edge_index.dtype == torch.int64


@pytest.mark.parametrize("backend", BACKENDS)
def test_far_apart_points_give_no_edges(backend):
    pos = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert radius_graph(pos, 0.5, backend=backend).shape == (2, 0)


def test_gradient_carrying_positions_are_accepted():
    pos = torch.rand(50, 3, dtype=torch.float64, requires_grad=True)
    assert torch.equal(radius_graph(pos, 0.3), brute_force(pos.detach(), 0.3))


# --- property tests against brute force -------------------------------------------------------


@st.composite
def point_clouds(draw):
    """(pos, radius): uniform, clustered (with duplicates) or on a coarse grid (exact ties)."""
    kind = draw(st.sampled_from(["uniform", "clustered", "grid"]))
    n = draw(st.integers(2, 80))
    dtype = draw(st.sampled_from([torch.float32, torch.float64]))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2**31 - 1)))
    scale = draw(st.sampled_from([1e-3, 1.0, 50.0]))  # m; also far from the origin below
    offset = draw(st.sampled_from([0.0, 10.0])) * scale
    if kind == "uniform":
        pos = torch.rand(n, 3, generator=g, dtype=torch.float64)
        radius = draw(st.floats(0.01, 1.0))
    elif kind == "clustered":
        num_clusters = draw(st.integers(1, 4))
        centres = torch.rand(num_clusters, 3, generator=g, dtype=torch.float64)
        which = torch.randint(num_clusters, (n,), generator=g)
        spread = draw(st.sampled_from([1e-4, 1e-2, 0.1]))
        pos = centres[which] + spread * torch.randn(n, 3, generator=g, dtype=torch.float64)
        num_dup = draw(st.integers(0, n // 4))
        pos[:num_dup] = pos[n - num_dup :]  # exact duplicates
        radius = draw(st.floats(1e-3, 0.5))
    else:  # multiples of 1/4 and an integer-ish radius: many pairs exactly at the radius
        pos = torch.randint(0, 8, (n, 3), generator=g).double() / 4
        radius = draw(st.sampled_from([0.25, 0.5, 0.75, 1.0, math.sqrt(2) / 2]))
        scale, offset = draw(st.sampled_from([1.0, 0.5, 2.0])), 0.0
    return (pos * scale + offset).to(dtype), radius * scale


@settings(max_examples=200, deadline=None)
@given(point_clouds())
def test_both_backends_equal_brute_force(cloud):
    pos, radius = cloud
    expected = brute_force(pos, radius)
    for backend in BACKENDS:
        got = radius_graph(pos, radius, backend=backend)
        assert got.dtype == torch.int64
        assert torch.equal(got, expected), f"{backend} differs from brute force"
    assert_matches_cdist(expected, pos, radius)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([torch.float32, torch.float64]))
def test_packed_particles_both_backends_identical(seed, dtype):
    # Like the simulator's input: a jittered 3 mm lattice, cut-off 2.5 spacings (~60 neighbours).
    g = torch.Generator().manual_seed(seed)
    axis = torch.arange(8, dtype=torch.float64) * 0.003
    pos = torch.cartesian_prod(axis, axis, axis)
    pos = (pos + 0.0006 * (torch.rand(pos.shape, generator=g, dtype=torch.float64) - 0.5)).to(dtype)
    by_scipy = radius_graph(pos, 0.0075, backend="scipy")
    assert torch.equal(by_scipy, radius_graph(pos, 0.0075, backend="torch_cluster"))
    assert torch.equal(by_scipy, brute_force(pos, 0.0075))


@settings(max_examples=150, deadline=None)
@given(point_clouds(), st.integers(2, 4))
def test_slab_parallel_scipy_search_equals_brute_force(cloud, threads):
    # The scipy search cut into one slab per thread (forced on small clouds): pairs across slab
    # faces, points exactly on a face and duplicates straddling it must all come out once.
    pos, radius = cloud
    with _slabs_from(2), _torch_threads(threads):
        got = radius_graph(pos, radius, backend="scipy")
    assert torch.equal(got, brute_force(pos, radius))


def test_slab_search_is_used_and_exact_on_a_long_packed_bed():
    # 12 x 4 x 4 lattice columns: thick enough for 3 slabs of >= 1 cut-off each.
    g = torch.Generator().manual_seed(3)
    pos = torch.cartesian_prod(
        torch.arange(36.0), torch.arange(4.0), torch.arange(4.0)
    ) * 0.003 + 0.0006 * (torch.rand(36 * 16, 3, generator=g) - 0.5)
    pos = pos.float()
    x = pos[:, 0].double().numpy()
    assert rg._slabs(x, 3, rg._search_radius(0.0075, pos.dtype)) is not None
    with _slabs_from(2), _torch_threads(3):
        got = radius_graph(pos, 0.0075, backend="scipy")
    assert torch.equal(got, brute_force(pos, 0.0075))


def test_slabs_thinner_than_the_cut_off_fall_back_to_one_search():
    x = np.linspace(0.0, 0.01, 100)  # 1 cm long: 4 slabs would be 2.5 mm thick
    assert rg._slabs(x, 4, 0.0075) is None
    assert rg._slabs(x, 2, 0.0075) is not None  # two slabs share one face: any thickness


def test_edges_are_symmetric_sorted_and_loop_free():
    pos = torch.rand(300, 3, generator=torch.Generator().manual_seed(0))
    edge_index = radius_graph(pos, 0.2)
    source, target = edge_index
    assert not (source == target).any()
    keys = target * 300 + source
    assert (keys[1:] > keys[:-1]).all(), "not strictly sorted by (target, source)"
    assert edge_set(edge_index) == edge_set(edge_index.flip(0))


# --- never truncated --------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_dense_cluster_gets_every_edge_without_a_cap(backend):
    # 400 points within 1 mm: every node has 399 neighbours at a 5 mm cut-off (PyG's default
    # cap of 32, or a fixed 64, would drop most of them).
    g = torch.Generator().manual_seed(1)
    cluster = 0.001 * torch.rand(400, 3, generator=g)
    sparse = 0.1 + torch.rand(100, 3, generator=g)
    pos = torch.cat([cluster, sparse])
    edge_index = radius_graph(pos, 0.005, backend=backend, max_num_neighbors=None)
    assert torch.equal(edge_index, brute_force(pos, 0.005))
    assert int(torch.bincount(edge_index[1]).max()) == 399


def test_cap_doubling_search_finds_every_neighbour_from_a_small_first_cap():
    # The CUDA path starts torch_cluster at a small cap and doubles while a node reaches it;
    # exercised here on the CPU from a first cap of 4. 150 points within 1 cm (149 neighbours
    # each) and 27 lattice points 20 cm apart: no distance near the 5 cm cut-off.
    g = torch.Generator().manual_seed(2)
    axis = 0.5 + 0.2 * torch.arange(3.0)
    pos = torch.cat(
        [0.01 * torch.rand(150, 3, generator=g), torch.cartesian_prod(axis, axis, axis)]
    )
    target, source = _torch_cluster_candidates(pos, 0.05, first_cap=4)
    not_self = target != source
    found = torch.stack([source[not_self], target[not_self]])
    assert edge_set(found) == edge_set(brute_force(pos, 0.05))
    assert len(edge_set(found)) == 150 * 149


@pytest.mark.parametrize("backend", BACKENDS)
def test_too_small_max_num_neighbors_raises_naming_the_fix(backend):
    pos = 0.001 * torch.rand(100, 3, generator=torch.Generator().manual_seed(3))
    with pytest.raises(InputError, match="max_num_neighbors") as info:
        radius_graph(pos, 0.01, backend=backend, max_num_neighbors=64)
    message = str(info.value)
    assert "100 of 100 nodes" in message
    assert "max degree 99" in message
    assert "pass None to size it automatically" in message


@pytest.mark.parametrize("backend", BACKENDS)
def test_max_num_neighbors_equal_to_the_true_degree_is_accepted(backend):
    # Every node has exactly 9 neighbours: a cap of 9 is reached but not exceeded.
    pos = 0.001 * torch.rand(10, 3, generator=torch.Generator().manual_seed(4))
    edge_index = radius_graph(pos, 0.01, backend=backend, max_num_neighbors=9)
    assert torch.equal(edge_index, brute_force(pos, 0.01))
    with pytest.raises(InputError, match="max degree 9"):
        radius_graph(pos, 0.01, backend=backend, max_num_neighbors=8)


# --- the transform ----------------------------------------------------------------------------


def test_transform_sets_edge_index_on_data():
    pos = 0.05 * torch.rand(200, 3, generator=torch.Generator().manual_seed(5))
    data = Data(pos=pos, x=torch.ones(200, 1))
    out = RadiusGraph(0.0075)(data)
    assert torch.equal(out.edge_index, brute_force(pos, 0.0075))
    assert torch.equal(out.pos, pos) and out.x.shape == (200, 1)


def test_transform_repr_is_short():
    assert repr(RadiusGraph(0.0075)) == "RadiusGraph(radius=0.0075, backend=auto)"
    assert (
        repr(RadiusGraph(0.01, "scipy", max_num_neighbors=80))
        == "RadiusGraph(radius=0.01, backend=scipy, max_num_neighbors=80)"
    )


def test_transform_without_pos_names_the_field():
    with pytest.raises(InputError, match=r"data\.pos"):
        RadiusGraph(0.01)(Data(x=torch.ones(3, 1)))


def test_transform_with_nan_pos_names_the_field():
    pos = torch.zeros(4, 3)
    pos[2, 1] = float("nan")
    with pytest.raises(InputError, match=r"data\.pos: 1 row\(s\) contain NaN"):
        RadiusGraph(0.01)(Data(pos=pos))


# --- bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pos", "match"),
    [
        (torch.tensor([[0.0, float("nan"), 0.0], [1.0, 1.0, 1.0]]), r"pos: 1 row\(s\) contain NaN"),
        (torch.tensor([[0.0, float("inf"), 0.0], [1.0, 1.0, 1.0]]), r"pos: 1 row\(s\) contain NaN"),
        (torch.zeros(5, 2), r"pos: expected shape \[\*, 3\], got \[5, 2\]"),
        (torch.zeros(3), r"pos: expected shape \[\*, 3\], got \[3\]"),
        (torch.zeros(4, 3, dtype=torch.int64), "pos: expected float32 or float64"),
        ([[0.0, 0.0, 0.0]], "pos: expected a torch.Tensor"),
    ],
)
def test_bad_pos_raises_input_error(pos, match):
    with pytest.raises(InputError, match=match):
        radius_graph(pos, 1.0)


@pytest.mark.parametrize("radius", [0.0, -0.1, float("nan"), float("inf"), "1", None, True])
def test_bad_radius_raises_input_error(radius):
    with pytest.raises(InputError, match="radius: expected a positive finite distance"):
        radius_graph(torch.zeros(4, 3), radius)
    with pytest.raises(InputError, match="radius: expected a positive finite distance"):
        RadiusGraph(radius)


def test_unknown_backend_raises_input_error():
    with pytest.raises(InputError, match="backend: expected one of 'auto', 'scipy'"):
        radius_graph(torch.zeros(4, 3), 1.0, backend="faiss")
    with pytest.raises(InputError, match="backend"):
        RadiusGraph(1.0, backend="kdtree")


@pytest.mark.parametrize("cap", [0, -3, 2.5, True])
def test_bad_max_num_neighbors_raises_input_error(cap):
    with pytest.raises(InputError, match="max_num_neighbors: expected a positive int or None"):
        radius_graph(torch.zeros(4, 3), 1.0, max_num_neighbors=cap)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("backend", ("auto", *BACKENDS))
def test_cuda_positions_give_the_cpu_result_on_the_same_device(backend):
    if backend == "torch_cluster":
        pytest.importorskip("torch_cluster")
    g = torch.Generator().manual_seed(6)
    pos = torch.cat([0.001 * torch.rand(300, 3, generator=g), torch.rand(200, 3, generator=g)])
    edge_index = radius_graph(pos.cuda(), 0.01, backend=backend)
    assert edge_index.device.type == "cuda"
    assert torch.equal(edge_index.cpu(), brute_force(pos, 0.01))
