"""Robustness: non-finite predictions stop a rollout keeping its past, bad states are refused
with one clear error, and degenerate scenes (coincident particles, particles on triangle
vertices and edges, zero-area triangles, empty scenes, mixed winding) give finite steps. Ends
with a hypothesis fuzz test of one step on random scenes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from torch_geometric.data import Data

from granular_pyg.errors import InputError, NonFiniteError
from granular_pyg.inference import rollout_trajectory
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import Wall, WallSet
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.transforms import AddRandomWalkNoise

R = 0.0075  # m, cut-off


def _model(normals: str = "both", seed: int = 0) -> LearnedSimulator:
    torch.manual_seed(seed)
    sim = LearnedSimulator(
        Processor(latent=16, num_steps=2, aggr="mean"), radius=R, normals=normals, latent=16
    )
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    return sim.eval()


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


def _resting(pos: np.ndarray, history: int = 5) -> torch.Tensor:
    """``[N, H + 1, 3]`` float32 history of particles at rest at ``pos [N, 3]`` (m)."""
    return torch.from_numpy(np.repeat(pos[:, None], history + 1, axis=1)).float()


def _box_walls(extra: list[Wall] | None = None) -> WallSet:
    """A floor: two triangles of the square [-1, 1]^2 cm at z = 0, plus ``extra`` walls."""
    v = np.array([[-0.01, -0.01, 0], [0.01, -0.01, 0], [0.01, 0.01, 0], [-0.01, 0.01, 0]])
    floor = Wall("floor", v, np.array([[0, 1, 2], [0, 2, 3]]))
    return WallSet([floor, *(extra or [])])


# --- non-finite predictions: stop, name the step and particles, keep the past ------------------


def test_nan_prediction_stops_the_rollout_naming_step_and_particles_and_keeps_the_past(hopper):
    sim = _model()
    sim.dt.fill_(0.0025)
    calls = {"n": 0}
    real = sim.predict_acceleration

    def fails_on_third_call(seq, *args, **kwargs):
        acc = real(seq, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 3:
            acc[7] = float("nan")
        return acc

    clean = rollout_trajectory(sim, hopper, steps=2, progress=False)
    sim.predict_acceleration = fails_on_third_call
    with pytest.raises(NonFiniteError, match=r"learned step 2: .*rows \[7\]") as info:
        rollout_trajectory(sim, hopper, steps=5, progress=False)
    exc = info.value
    assert exc.step == 2 and exc.particle_ids == [7]
    partial = exc.partial
    assert partial.num_frames == 6 + 2 and partial.metadata["failed_step"] == 2
    np.testing.assert_array_equal(partial.positions, clean.positions)


@pytest.mark.parametrize(
    ("corrupt", "match"),
    [
        (lambda s: s.__setitem__((4, 2, 0), float("inf")), r"rows \[4\]"),
        (lambda s: s.__setitem__((5, -1, 1), float("nan")), r"NaN in only some coordinates"),
        (lambda s: s.__setitem__((6, 0), float("nan")), r"finite after NaN: rows \[6\]"),
    ],
    ids=["inf", "partly-nan", "back-after-leaving"],
)
def test_bad_particle_states_are_refused_naming_the_rows(hopper, corrupt, match):
    seq = torch.from_numpy(hopper.positions[:6]).permute(1, 0, 2).contiguous()
    corrupt(seq)
    with pytest.raises(InputError, match=match):
        _model().step(seq, WallSet(hopper.scene), 0.0125)


def test_coordinates_too_large_for_float32_are_refused_and_float64_works():
    far = np.array([[100.0, 100.0, 100.0], [100.003, 100.0, 100.0]])
    walls = WallSet(
        [Wall("w", np.array([[100, 99, 99], [101, 99, 99], [100, 101, 99.0]]), [[0, 1, 2]])]
    )
    with pytest.raises(InputError, match=r"dtype=float64"):
        _model().step(_resting(far), walls, 0.0)
    out = _model().step(_resting(far).double(), walls, 0.0)
    assert out.dtype == torch.float64 and torch.isfinite(out).all()


# --- degenerate scenes give finite steps -------------------------------------------------------


def test_coincident_particles_give_a_finite_step():
    pos = np.array([[0.0, 0.0, 0.002], [0.0, 0.0, 0.002], [0.003, 0.0, 0.002]])
    out = _model().step(_resting(pos), _box_walls(), 0.0)
    assert torch.isfinite(out).all()


def test_particles_exactly_on_triangle_vertices_and_edges_give_finite_steps():
    # On a corner vertex, on the shared diagonal edge, on an outer edge: zero distance to the
    # wall, so the wall-node displacement is zero-length.
    pos = np.array([[-0.01, -0.01, 0.0], [0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.005, 0.001]])
    sim = _model()
    graph = sim.build_graph(_resting(pos), _box_walls(), 0.0)
    assert int(graph.is_wall.sum()) >= 3  # a wall node for each particle on the floor
    assert torch.isfinite(graph.x).all() and torch.isfinite(graph.edge_attr).all()
    assert torch.isfinite(sim.step(_resting(pos), _box_walls(), 0.0)).all()


def test_zero_area_triangles_give_finite_steps():
    # Repeated vertex and collinear vertices, right under the particles.
    v = np.array([[0, 0, -0.001], [0.004, 0, -0.001], [0.008, 0, -0.001]])
    sliver = Wall("sliver", v, np.array([[0, 1, 1], [0, 1, 2]]))
    pos = np.array([[0.0, 0.0, 0.001], [0.004, 0.0, 0.0005]])
    out = _model().step(_resting(pos), _box_walls([sliver]), 0.0)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("num_particles", [0, 1])
def test_scenes_with_no_or_one_particle(num_particles):
    pos = np.tile([0.0, 0.0, 0.003], (num_particles, 1))
    out = _model().step(_resting(pos), _box_walls(), 0.0)
    assert out.shape == (num_particles, 3) and torch.isfinite(out).all()


def test_mixed_winding_does_not_change_a_v3_prediction(hopper):
    # Flip a random half of the triangles of every wall: V3 sorts both orientations.
    rng = np.random.default_rng(0)
    flipped = []
    for wall in hopper.scene.walls:
        faces = wall.faces.copy()
        pick = rng.random(len(faces)) < 0.5
        faces[pick] = faces[pick][:, [0, 2, 1]]
        flipped.append(dataclasses.replace(wall, faces=faces))
    seq = torch.from_numpy(hopper.positions[30:36]).permute(1, 0, 2).contiguous()
    seq = seq[torch.isfinite(seq).all(2).all(1)]
    sim = _model("both")
    a = sim.step(seq, WallSet(hopper.scene), 0.09)
    b = sim.step(seq, WallSet(flipped), 0.09)
    torch.testing.assert_close(a, b, rtol=0, atol=1e-9)


# --- fuzz: random scenes, degenerate ones included ---------------------------------------------


@st.composite
def scenes(draw):
    """(positions history [N, 6, 3] float32, walls): random particles near random triangles,
    with coincident particles, particles on vertices and zero-area triangles mixed in."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = draw(st.integers(0, 40))
    num_tri = draw(st.integers(1, 6))
    vertices = rng.uniform(-0.01, 0.01, (3 * num_tri, 3))
    faces = np.arange(3 * num_tri).reshape(num_tri, 3)
    kind = draw(st.sampled_from(["plain", "repeated", "collinear"]))
    if kind == "repeated":
        faces[0, 2] = faces[0, 1]
    elif kind == "collinear":
        vertices[2] = 0.5 * (vertices[0] + vertices[1])
    pos = rng.uniform(-0.012, 0.012, (n, 3))
    if n >= 2 and draw(st.booleans()):
        pos[1] = pos[0]  # coincident
    if n >= 3 and draw(st.booleans()):
        pos[2] = vertices[0]  # on a vertex
    step = rng.normal(0.0, draw(st.sampled_from([0.0, 1e-5, 1e-3])), (n, 6, 3))
    history = pos[:, None] + np.cumsum(step, axis=1)
    gone = rng.random(n) < draw(st.sampled_from([0.0, 0.3, 1.0]))
    history[gone] = np.nan  # particles that have left
    return torch.from_numpy(history).float(), WallSet([Wall("w", vertices, faces)])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes(), st.sampled_from(["none", "single", "both"]), st.sampled_from([0.0, 1e-4]))
def test_noise_and_one_step_on_random_scenes_stay_finite(scene, normals, noise_std):
    # The training transform (random-walk noise, resampled at walls) on the present particles,
    # then one step through the graph transforms (radius graph, wall nodes) and the network.
    seq, walls = scene
    present = torch.isfinite(seq).all(2).all(1)
    if noise_std and bool(present.any()):
        data = Data(pos_seq=seq[present], target_pos=seq[present, -1], walls=walls, time=0.0)
        data = AddRandomWalkNoise(noise_std, True, generator=torch.Generator().manual_seed(0))(data)
        assert torch.isfinite(data.pos_seq).all() and torch.isfinite(data.target_pos).all()
        seq = seq.clone()
        seq[present] = data.pos_seq
    out = _model(normals).step(seq, walls, 0.0)
    assert out.shape == (seq.shape[0], 3)
    assert torch.isfinite(out[present]).all()
    assert torch.isnan(out[~present]).all()
