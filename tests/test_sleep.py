"""``model.sleep``: a particle at rest beyond the reach of anything that moves or changes gets
zero acceleration. A bed at rest is held to the bit, a bed at rest in mid-air falls, a flowing
bed is unchanged, a lid's removal or a moving wall wakes what the model can reach, news spreads
``num_steps`` hops a step, and the rule turns and mirrors with the scene."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scipy.sparse.csgraph import shortest_path

from granular_pyg.checkpoint.saved_config import migrate_config
from granular_pyg.errors import InputError
from granular_pyg.evaluation.variants import held_still
from granular_pyg.geometry import horizontal_frame
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.scenes.redescribe import turned_scene
from granular_pyg.simulator import ParticleProps
from granular_pyg.sleep import REST_SPEED, WAKE_ACCELERATION, at_rest, spread, supported
from tests.test_symmetries import _sim, _window


def _quiet(processor: str = "equivariant", sleep: bool = True, fall: float = 0.0):
    """A random model whose accelerations are a few 0.1 m/s^2 about ``(0, 0, -fall)``: below
    ``WAKE_ACCELERATION`` where ``fall`` is 0 (a settled bed's errors), above it at g."""
    sim = _sim(processor, "both", sleep=sleep)
    sim.set_normalization([0.0, 0.0, 0.0], [0.1, 0.1, 0.1], [0.0, 0.0, -fall], [0.1, 0.1, 0.1])
    return sim


def _bed(sample: str = "hopper", frame: int = 0):
    """The bundled ``sample``'s bed at ``frame`` held: a history at rest, the trajectory, the
    time and the particle properties."""
    traj = read_trajectory(sample_files(sample)[0])
    keep = np.isfinite(traj.positions[frame]).all(1)
    seq = torch.from_numpy(traj.positions[frame][keep]).double()[:, None].repeat(1, 6, 1)
    return traj, seq, float(traj.times[frame]), ParticleProps.of(traj)[torch.from_numpy(keep)]


def test_at_rest_tiny_cases():
    dt = 0.01
    seq = torch.zeros(3, 3, 3, dtype=torch.float64)
    seq[1, 2, 0] = 0.5 * REST_SPEED * dt  # slower than REST_SPEED: at rest
    seq[2, 1:, 2] = -REST_SPEED * dt  # one step at REST_SPEED: moving
    assert at_rest(seq, dt).tolist() == [True, True, False]


def _chain(n: int = 6):
    """``n`` particle nodes on a chain of edges both ways, plus a wall node joined to both
    ends: ``(edge_index, is_wall)``."""
    pairs = [(i, i + 1) for i in range(n - 1)] + [(n, 0), (n, n - 1)]
    edge_index = torch.tensor(pairs + [(j, i) for i, j in pairs]).T
    return edge_index, torch.tensor([False] * n + [True])


@pytest.mark.parametrize(
    "moving, hops, want",
    [
        ([0], 2, [1, 1, 1, 0, 0, 0]),
        ([0], 0, [1, 0, 0, 0, 0, 0]),
        ([], 3, [0, 0, 0, 0, 0, 0]),  # nothing moves: everything sleeps
        ([3], 2, [0, 1, 1, 1, 1, 1]),
        ([5], 1, [0, 0, 0, 0, 1, 1]),  # news does not pass through the wall node to 0
    ],
)
def test_spread_tiny_cases(moving, hops, want):
    edge_index, is_wall = _chain()
    awake = torch.zeros(7, dtype=torch.bool)
    awake[moving] = True
    assert spread(awake, edge_index, is_wall, hops)[:6].int().tolist() == want


@pytest.mark.parametrize(
    "awake, want",
    [
        ([2], [0, 0, 1, 0, 0, 0]),  # a lone mover wakes nothing
        ([1, 3], [0, 1, 1, 1, 0, 0]),  # node 2 has two awake neighbours
        ([0, 1], [1, 1, 0, 0, 0, 0]),  # node 2 has one
    ],
)
def test_spread_with_a_quorum_of_two(awake, want):
    edge_index, is_wall = _chain()
    seeds = torch.zeros(7, dtype=torch.bool)
    seeds[awake] = True
    assert spread(seeds, edge_index, is_wall, 3, quorum=2)[:6].int().tolist() == want


@pytest.mark.parametrize("seed", range(4))
def test_spread_matches_hop_distances_on_random_graphs(seed):
    g = torch.Generator().manual_seed(seed)
    n, w, hops = 30, 4, 2
    edge_index = torch.randint(n + w, (2, 60), generator=g)
    is_wall = torch.arange(n + w) >= n
    awake = torch.zeros(n + w, dtype=torch.bool)
    awake[:n] = torch.rand(n, generator=g) < 0.1
    got = spread(awake, edge_index, is_wall, hops)[:n]
    adj = np.zeros((n, n))  # brute force: hop distances over particle-to-particle edges
    for s, d in edge_index.T.tolist():
        if s < n and d < n:
            adj[s, d] = 1
    dist = shortest_path(adj, unweighted=True)
    start = awake[:n].numpy()
    want = (dist[start] <= hops).any(axis=0) if start.any() else np.zeros(n, bool)
    assert got.tolist() == want.tolist()


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
def test_a_sleeping_bed_is_held_to_the_bit(processor):
    traj, seq, t, props = _bed()
    walls = WallSet(held_still(traj, 0.1).scene)  # the lid never removed
    awake_model, sleeping = _quiet(processor, sleep=False), _quiet(processor)
    start, moved = seq.clone(), seq.clone()
    for k in range(10):
        time = t + k * float(sleeping.dt)
        seq = torch.cat([seq[:, 1:], sleeping.step(seq, walls, time, props=props)[:, None]], 1)
        nxt = awake_model.step(moved, walls, time, props=props)
        moved = torch.cat([moved[:, 1:], nxt[:, None]], 1)
    assert torch.equal(seq, start)
    assert not torch.equal(moved, start)  # the same network without sleeping sinks
    with torch.no_grad():
        acc = awake_model.predict_acceleration(start, walls, t, props=props)  # same weights
    assert 0 < float(acc.norm(dim=1).max()) < WAKE_ACCELERATION  # held for want of news


def test_a_rattler_moves_nothing_but_itself():
    sim = _quiet()
    traj, seq, t, props = _bed()
    walls = WallSet(held_still(traj, 0.1).scene)
    rattler = int(torch.argmin((seq[:, -1] - seq[:, -1].mean(0)).norm(dim=1)))  # mid-bed
    seq = seq.clone()
    seq[rattler, -1, 0] += 0.011 * float(sim.dt)  # 11 mm/s in its last step
    nxt = sim.step(seq, walls, t, props=props)
    moved = (nxt - seq[:, -1]).norm(dim=1) > 0
    assert moved.nonzero().flatten().tolist() == [rattler]


def test_a_bed_at_rest_in_mid_air_wakes_and_falls():
    traj, seq, t, props = _bed()
    walls = WallSet(held_still(traj, 0.1).scene)
    falling = _quiet(fall=9.81)  # the network gives g: no support
    nxt = falling.step(seq, walls, t, props=props)
    assert ((nxt - seq[:, -1])[:, 2] < 0).all()


def test_supported_tiny_cases():
    # node 1 rests on 0 (straight below), node 2 has 1 at 45 degrees below, node 3 has 2 level
    # with it and 1 at 26.6 degrees below (under the 30 degree cone): nothing beneath
    pos = torch.tensor([[0.0, 0, 0], [0, 0, 1], [1, 0, 2], [2, 0, 2]])
    pairs = [(0, 1), (1, 2), (2, 3), (1, 3)]
    edge_index = torch.tensor(pairs + [(j, i) for i, j in pairs]).T
    assert supported(pos, edge_index).tolist() == [False, True, True, False]
    # the same in any frame turned about gravity and mirrored
    q = horizontal_frame(123.0, mirror=True).float()
    assert torch.equal(supported(pos @ q.T, edge_index), supported(pos, edge_index))


def test_a_bed_lifted_off_its_lid_wakes_from_below():
    sim = _quiet()  # the network gives a few 0.1 m/s^2: too little to wake anything itself
    traj, seq, t, props = _bed()
    scene = held_still(traj, 0.1).scene
    walls = WallSet(dataclasses.replace(scene, walls=[w for w in scene.walls if w.name == "lid"]))
    with torch.no_grad():
        on_lid = sim.build_graph(seq, walls, t, props=props)
        acc = sim.predict_acceleration(seq, walls, t, props=props)
    assert supported(on_lid.pos, on_lid.edge_index)[~on_lid.is_wall].all()
    assert not acc.any()  # resting on its lid: asleep
    lifted = seq + torch.tensor([0.0, 0.0, 0.05], dtype=seq.dtype)  # 5 cm above the lid
    with torch.no_grad():
        graph = sim.build_graph(lifted, walls, t, props=props)
        acc = sim.predict_acceleration(lifted, walls, t, props=props)
    z = lifted[:, -1, 2]
    lowest = z < z.min() + 1e-4
    below = supported(graph.pos, graph.edge_index)[~graph.is_wall]
    assert not below[lowest].any()  # nothing under the lowest particles
    assert acc[lowest].abs().sum(1).gt(0).all()  # they wake, and so does what they reach
    assert acc.abs().sum(1).gt(0).float().mean() > 0.1


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
def test_a_flowing_bed_is_unchanged(processor):
    traj, seq, t, present = _window("hopper", 30)  # flowing, the lid gone
    props = ParticleProps.of(traj)[present]
    walls = WallSet(traj.scene)
    plain, sleeping = _quiet(processor, sleep=False), _quiet(processor)
    with torch.no_grad():
        a = plain.predict_acceleration(seq, walls, t, props=props)
        b = sleeping.predict_acceleration(seq, walls, t, props=props)
        graph = sleeping.build_graph(seq, walls, t, props=props)
        awake = sleeping.awake(seq, graph, walls, t, a)
    assert awake.float().mean() > 0.9
    assert torch.equal(b[awake], a[awake]) and not b[~awake].any()


def test_a_lid_removed_wakes_what_the_model_reaches_for_its_step_only():
    sim = _quiet()
    traj, seq, _, props = _bed()
    walls, dt = WallSet(traj.scene), float(sim.dt)  # the lid is removed at 0.02 s
    removal = walls.event_times()[0]
    bottom = seq[:, -1, 2] < seq[:, -1, 2].min() + 0.002  # the layer on the lid
    for t, wakes in ((removal - dt, False), (removal - 0.5 * dt, True), (removal, True)):
        woken = sim.woken_by_walls(seq[:, -1], walls, t)
        assert (woken is not None) == wakes  # a removal at the step's end wakes nothing
        nxt = sim.step(seq, walls, t, props=props)
        moved = (nxt - seq[:, -1]).norm(dim=1) > 0
        if wakes:  # within reach: the network's own acceleration; beyond: asleep, at rest
            near = walls.near(seq[:, -1], sim.reach, t, walls.changing(t, t + dt))
            assert torch.equal(woken, near) and woken[bottom].all() and not woken.all()
            assert moved[woken].all() and not moved.all()  # (and what lost its support)
        else:
            assert not moved.any()
    assert sim.woken_by_walls(seq[:, -1], walls, removal + dt) is None  # the next step


def test_a_moving_wall_wakes_the_particles_it_reaches():
    sim = _sim("equivariant", "both", sleep=True)
    traj, seq, t, _ = _bed("drum")  # the bundled drum turns from t = 0
    walls = WallSet(traj.scene)
    woken = sim.woken_by_walls(seq[:, -1], walls, t + 0.1)
    assert woken is not None and woken.any()
    assert torch.equal(woken, walls.near(seq[:, -1], sim.reach, t + 0.1, walls.moving(t, t + 1)))
    held = WallSet(held_still(traj, 0.1).scene)  # the drum at rest: nothing wakes
    assert sim.woken_by_walls(seq[:, -1], held, t + 0.1) is None


def test_sleeping_does_not_act_in_a_training_pass():
    sim = _quiet().float()
    traj, seq, t, props = _bed()
    walls = WallSet(held_still(traj, 0.1).scene)
    seq = seq.float()
    with torch.no_grad():
        assert not sim.predict_acceleration(seq, walls, t, props=props).any()
    sim.train()
    acc = sim.predict_acceleration(seq, walls, t, props=props)
    assert acc.abs().min() > 0  # every particle learns its acceleration
    acc.square().sum().backward()
    assert all(p.grad is not None for p in sim.model.decoder.parameters())


@pytest.mark.parametrize("mirror", [False, True])
def test_sleeping_turns_and_mirrors_with_the_scene(mirror):
    sim = _quiet()
    traj, seq, _, props = _bed()
    walls = WallSet(traj.scene)
    t = walls.event_times()[0] - 0.5 * float(sim.dt)  # part of the bed wakes
    q = horizontal_frame(211.0 if mirror else 37.0, mirror=mirror)
    with torch.no_grad():
        acc = sim.predict_acceleration(seq, walls, t, props=props)
        turned = WallSet(turned_scene(traj.scene, q))
        moved = sim.predict_acceleration(seq @ q.T, turned, t, props=props)
    assert acc.any() and not acc.all()
    assert torch.equal(moved.abs().sum(1) > 0, acc.abs().sum(1) > 0)
    assert torch.allclose(moved, acc @ q.T, atol=1e-5 * float(acc.abs().max()), rtol=0)


def test_older_checkpoints_do_not_sleep_and_a_removed_rest_gate_is_refused():
    old = {"model": {"normals": "both"}, "data": {}}
    assert migrate_config(old)["model"]["sleep"] is False
    for section, key, value in (("model", "rest_gate", True), ("data", "clean_share", 0.25)):
        cfg = {"model": {"normals": "both"}, "data": {}}
        cfg[section][key] = value
        with pytest.raises(InputError, match=rf"{section}\.{key}"):
            migrate_config(cfg)
    assert "rest_gate" not in migrate_config(old | {"model": {"rest_gate": False}})["model"]


def test_sleep_must_be_a_flag():
    with pytest.raises(InputError, match=r"model\.sleep"):
        _sim("bgnn", "both", sleep="yes")
