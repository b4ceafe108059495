"""LearnedSimulator: features, wall-normal variants, invariances, batching, integration."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from torch_geometric.data import Batch, Data

from granular_pyg.errors import InputError
from granular_pyg.geometry import dense_wall_pairs
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator

FRAME = 30  # flowing, lid gone, particles at the walls


@pytest.fixture(scope="module")
def hopper():
    traj = read_trajectory(sample_files("hopper")[0])
    window = torch.from_numpy(traj.positions[FRAME - 5 : FRAME + 2]).permute(1, 0, 2)
    present = torch.isfinite(window).all(2).all(1)
    window = window[present].contiguous()
    return traj, window[:, :-1], float(traj.times[FRAME]), window[:, -1]


def _model(normals="both", seed=0, **kwargs) -> LearnedSimulator:
    torch.manual_seed(seed)
    options = dict(radius=0.0075, normals=normals, latent=32, dt=0.0025) | kwargs
    sim = LearnedSimulator(Processor(latent=32, num_steps=2, aggr="mean"), **options)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    return sim.eval()


def _walls(scene, flip=False, shift=0.0, reverse=False) -> WallSet:
    walls = []
    for wall in scene.walls:
        faces = wall.faces[:, [0, 2, 1]] if flip else wall.faces
        faces = faces[::-1].copy() if reverse else faces
        walls.append(dataclasses.replace(wall, vertices=wall.vertices + shift, faces=faces))
    return WallSet(walls)


def test_features_and_graph_shapes(hopper):
    traj, seq, t, _ = hopper
    sim = _model()
    graph = sim.build_graph(seq, WallSet(traj.scene), t)
    num_real = seq.shape[0]
    num_wall = int(graph.is_wall.sum())
    assert graph.num_real == num_real and num_wall > 0
    assert graph.x.shape == (num_real + num_wall, 3 * 5 + 6 + 2)
    assert graph.edge_attr.shape == (graph.edge_index.shape[1], 4)
    # Wall edges run wall -> particle only.
    _src, dst = graph.edge_index
    assert not graph.is_wall[dst].any()
    assert (graph.edge_attr[:, 3] < 1.0).all()  # |x_i - x_j| / R < 1
    assert sim(graph).shape == (num_real, 3)


def test_exactly_one_wall_node_per_near_pair(hopper):
    traj, seq, t, _ = hopper
    walls = WallSet(traj.scene)
    graph = _model().wall_nodes(_model().radius_graph(_data(seq, walls, t)))
    present = [w for w in traj.scene.walls if w.present(t)]
    triangles = torch.cat([torch.from_numpy(w.triangles) for w in present]).float()
    dense = dense_wall_pairs(seq[:, -1], triangles, 0.0075)
    _src, dst = graph.edge_index[:, graph.is_wall[graph.edge_index[0]]]
    got = sorted(zip(dst.tolist(), graph.wall_tri.tolist(), strict=True))
    assert got == sorted(zip(dense.point_idx.tolist(), dense.tri_idx.tolist(), strict=True))
    assert len(got) > 0


def _data(seq, walls, t) -> Data:
    return Data(pos=seq[:, -1], walls=walls, time=t)


def test_v3_is_identical_when_every_triangle_is_flipped(hopper):
    traj, seq, t, _ = hopper
    sim = _model("both")
    a = sim(sim.build_graph(seq, _walls(traj.scene), t))
    b = sim(sim.build_graph(seq, _walls(traj.scene, flip=True), t))
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)


def test_v1_ignores_normals_and_v2_does_not(hopper):
    traj, seq, t, _ = hopper
    v1, v2 = _model("none"), _model("single")
    g1 = v1.build_graph(seq, _walls(traj.scene), t)
    assert (g1.x[g1.is_wall][:, 15:21] == 0).all()
    flipped = _walls(traj.scene, flip=True)
    torch.testing.assert_close(v1(g1), v1(v1.build_graph(seq, flipped, t)), rtol=1e-5, atol=1e-5)
    a2 = v2(v2.build_graph(seq, _walls(traj.scene), t))
    b2 = v2(v2.build_graph(seq, flipped, t))
    assert (a2 - b2).abs().max() > 1e-5  # the winding changes V2's answer (V3: ~1e-7)


def _relative_change(sim, seq, scene, t, offset) -> float:
    base = sim(sim.build_graph(seq, _walls(scene), t))
    moved = sim(sim.build_graph(seq + offset, _walls(scene, shift=offset), t))
    return float((moved - base).abs().max().detach() / base.abs().max().detach())


@pytest.mark.parametrize("offset", [1.0, 1000.0])
def test_translation_invariance_with_float64_positions(hopper, offset):
    traj, seq, t, _ = hopper
    assert _relative_change(_model(), seq.double(), traj.scene, t, offset) < 1e-5


def test_translation_invariance_with_float32_positions_holds_at_1_m(hopper):
    # float32 spacing at 1 m is 6e-8 m, ~1e-3 of a frame's displacement here (~1e-4 m): the
    # velocity features, and so the output, keep about three digits.
    traj, seq, t, _ = hopper
    assert _relative_change(_model(), seq, traj.scene, t, 1.0) < 1e-3


def test_permutation_equivariance_of_particles_and_invariance_to_triangle_order(hopper):
    traj, seq, t, _ = hopper
    sim = _model()
    base = sim(sim.build_graph(seq, _walls(traj.scene), t))
    perm = torch.randperm(seq.shape[0], generator=torch.Generator().manual_seed(1))
    permuted = sim(sim.build_graph(seq[perm], _walls(traj.scene), t))
    torch.testing.assert_close(permuted, base[perm], rtol=1e-5, atol=1e-5)
    reordered = sim(sim.build_graph(seq, _walls(traj.scene, reverse=True), t))
    torch.testing.assert_close(reordered, base, rtol=1e-5, atol=1e-5)


def test_batch_of_graphs_equals_separate_graphs(hopper):
    traj, seq, t, _ = hopper
    sim = _model()
    walls = WallSet(traj.scene)
    g1, g2 = sim.build_graph(seq, walls, t), sim.build_graph(seq[:300], walls, t)
    batched = sim(Batch.from_data_list([g1, g2]))
    torch.testing.assert_close(batched, torch.cat([sim(g1), sim(g2)]), rtol=1e-5, atol=1e-5)


def test_gradients_reach_every_parameter(hopper):
    traj, seq, t, next_pos = hopper
    sim = _model().train()
    target = sim.target_acceleration(seq, next_pos)
    loss = ((sim(sim.build_graph(seq, WallSet(traj.scene), t)) - target) ** 2).mean()
    loss.backward()
    for name, p in sim.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_semi_implicit_euler_and_masking_and_outflow(hopper):
    traj, seq, t, _ = hopper
    sim = _model()
    torch.nn.init.zeros_(sim.model.decoder[-1].weight)
    torch.nn.init.zeros_(sim.model.decoder[-1].bias)
    acc = torch.tensor([0.5, -0.25, -9.75])
    sim.set_normalization(sim.vel_mean, sim.vel_std, acc, sim.acc_std)  # network outputs 0
    seq64 = seq.double().clone()
    seq64[3] = float("nan")  # a particle that has left
    nxt = sim.step(seq64, WallSet(traj.scene), t)
    dt = 0.0025
    v = (seq64[:, -1] - seq64[:, -2]) / dt
    want = seq64[:, -1] + dt * (v + dt * acc.double())
    keep = torch.arange(seq.shape[0]) != 3
    torch.testing.assert_close(nxt[keep], want[keep], rtol=0, atol=1e-9)
    assert torch.isnan(nxt[3]).all()
    gone = sim.step(seq64, WallSet(traj.scene), t, outflow_z=float(seq64[:, -1, 2].nanmedian()))
    assert torch.isnan(gone[:, 2]).sum() >= seq.shape[0] // 2


def test_integrate_is_the_inverse_of_target_acceleration_and_carries_gradients(hopper):
    _, seq, _, _ = hopper
    sim = _model()
    seq64 = seq.double().clone().requires_grad_(True)
    acc = torch.randn(seq.shape[0], 3, dtype=torch.float64) * 5.0
    nxt = sim.integrate(seq64, acc)
    back = sim.target_acceleration(seq64, nxt).double() * sim.acc_std.double() + sim.acc_mean
    torch.testing.assert_close(back, acc, rtol=1e-5, atol=1e-5)
    nxt[:, 2].sum().backward()
    assert torch.equal(seq64.grad[:, -1, 2], torch.full((seq.shape[0],), 2.0, dtype=torch.float64))
    assert torch.equal(seq64.grad[:, -2, 2], torch.full((seq.shape[0],), -1.0, dtype=torch.float64))


def test_normalization_statistics_are_saved_with_the_module(tmp_path):
    sim = _model()
    torch.save(sim.state_dict(), tmp_path / "sim.pt")
    fresh = _model(seed=1)
    fresh.set_normalization([0.0] * 3, [1.0] * 3, [0.0] * 3, [1.0] * 3)
    fresh.load_state_dict(torch.load(tmp_path / "sim.pt"))
    assert torch.equal(fresh.acc_std, torch.tensor([5.0, 5.0, 8.0]))
    assert float(fresh.dt) == 0.0025


def test_no_particles_left_gives_all_nan(hopper):
    traj, _seq, t, _ = hopper
    empty = torch.full((4, 6, 3), float("nan"))
    assert torch.isnan(_model().step(empty, WallSet(traj.scene), t)).all()


def test_wall_nodes_carry_the_rotating_drum_velocity():
    traj = read_trajectory(sample_files("drum")[0])
    seq = torch.from_numpy(traj.positions[45:51]).permute(1, 0, 2).contiguous()
    sim = _model(radius=0.01)
    graph = sim.build_graph(seq, WallSet(traj.scene), float(traj.times[50]))
    wall_x = graph.x[graph.is_wall]
    weight = wall_x[:, -1:]  # the 1/k weight scales every wall feature
    wall_vel = wall_x[:, :3] / weight * sim.vel_std + sim.vel_mean
    speed = torch.linalg.vector_norm(wall_vel, dim=1)
    omega, radius = traj.scene.params["omega"], traj.scene.params["drum_radius"]
    assert np.isclose(float(speed.max()), omega * radius, rtol=0.05)


def test_a_wall_removed_during_the_step_is_gone_from_its_graph_with_walls_over_step():
    """The sample's lid goes at 0.02 s: LIGGGHTS's bed is still at rest in the frame at 0.02 s
    and falls from the next. A step from 0.018 s to 0.0205 s must not show the lid (the bed
    starts to fall during it); a step that ends at 0.02 s or before still does (the lid held
    the bed all through it); the option off (older checkpoints) shows the lid whenever it is
    there at the step's start."""
    traj = read_trajectory(sample_files("hopper")[0])
    assert [w.removal_time for w in traj.scene.walls] == [None, 0.02]
    seq = torch.from_numpy(traj.positions[0:6]).permute(1, 0, 2).contiguous()
    walls, hopper_only = WallSet(traj.scene), WallSet(traj.scene.walls[:1])

    def lid_nodes(sim, t):
        every = int(sim.build_graph(seq, walls, t).is_wall.sum())
        return every - int(sim.build_graph(seq, hopper_only, t).is_wall.sum())

    end, start = _model(walls_over_step=True), _model()
    assert float(end.dt) == 0.0025
    bottom = traj.positions[0, :, 2] < traj.positions[0, :, 2].min() + 0.004
    sink = traj.positions[0, bottom, 2] - traj.positions[[8, 9]][:, bottom, 2]  # 0.02, 0.0225 s
    assert abs(sink[0]).max() < 1e-7 and sink[1].mean() > 5e-5  # at rest at 0.02 s, then falling
    assert lid_nodes(start, 0.018) > 0 and lid_nodes(end, 0.018) == 0  # gone by 0.0205 s
    assert lid_nodes(end, 0.0175) == lid_nodes(start, 0.0175) > 0  # the step ends at 0.02 s
    assert lid_nodes(start, 0.02) == lid_nodes(end, 0.02) == 0  # already gone
    with pytest.raises(InputError, match="walls_over_step"):
        _model(walls_over_step="yes")
