"""The equivariant processor's ``global_context``: each step's node update also gets the mean
node scalars of the particles of its graph. Exact small cases, a brute-force batch reference,
the symmetries (turns, mirrors, shifts, re-meshing) and switching it on for a trained model."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.checkpoint.fine_tune import with_node_inputs
from granular_pyg.errors import InputError
from granular_pyg.geometry import horizontal_frame
from granular_pyg.nn import HorizontalEquivariantNetwork, HorizontalEquivariantProcessor
from granular_pyg.nn.horizontal_equivariant import graph_mean
from granular_pyg.scenes import WallSet
from granular_pyg.scenes.redescribe import subdivided_scene, turned_scene
from granular_pyg.simulator import LearnedSimulator, ParticleProps
from tests.test_symmetries import _window

LATENT, CHANNELS = 24, 6


def test_graph_mean_tiny_exact_case():
    s = torch.tensor([[1.0, 2.0], [3.0, 4.0], [100.0, 100.0], [5.0, -1.0], [-7.0, 0.0]])
    # graph 0: particles 0, 1 and a wall node; graph 1: particle 3, wall node 4
    index = torch.tensor([0, 0, -1, 1, -2])
    out = graph_mean(s, index)
    expected = torch.tensor([[2.0, 3.0], [2.0, 3.0], [2.0, 3.0], [5.0, -1.0], [5.0, -1.0]])
    assert torch.equal(out, expected)
    # a graph of wall nodes only gets zeros
    assert torch.equal(graph_mean(s[:3], torch.tensor([0, 0, -2]))[2], torch.zeros(2))


def _network(seed: int = 5, global_context: bool = True) -> HorizontalEquivariantNetwork:
    torch.manual_seed(seed)
    proc = HorizontalEquivariantProcessor(
        LATENT, num_steps=2, channels=CHANNELS, wall_sum=True, global_context=global_context
    )
    return HorizontalEquivariantNetwork(7, 3, 5, proc).double().eval()


def _random_graph(num: int, walls: int, edges: int, seed: int):
    """Network inputs of a random graph of ``num`` particles then ``walls`` wall nodes (wall
    nodes only send), and its ``[num + walls]`` wall mask."""
    g = torch.Generator().manual_seed(seed)
    n = num + walls
    edge_index = torch.stack(
        [torch.randint(0, n, (edges,), generator=g), torch.randint(0, num, (edges,), generator=g)]
    )
    inputs = (
        torch.randn(n, 7, generator=g, dtype=torch.float64),
        torch.randn(n, 3, 2, generator=g, dtype=torch.float64),
        edge_index,
        torch.randn(edges, 5, generator=g, dtype=torch.float64),
        torch.randn(edges, 2, generator=g, dtype=torch.float64),
        edge_index[0] >= num,
    )
    return inputs, torch.arange(n) >= num


def test_a_batch_equals_each_graph_alone():
    """The mean is per graph: two graphs batched give each graph's own output (brute force:
    each run alone), and not what one run over both as a single graph gives."""
    net = _network()
    (a, wall_a), (b, wall_b) = _random_graph(9, 3, 40, 1), _random_graph(6, 2, 25, 2)
    with torch.no_grad():
        alone = [net(*a, torch.where(wall_a, -1, 0)), net(*b, torch.where(wall_b, -1, 0))]
        offset = len(a[0])
        batch = (
            torch.cat([a[0], b[0]]),
            torch.cat([a[1], b[1]]),
            torch.cat([a[2], b[2] + offset], 1),
            torch.cat([a[3], b[3]]),
            torch.cat([a[4], b[4]]),
            torch.cat([a[5], b[5]]),
        )
        both = net(*batch, torch.cat([torch.where(wall_a, -1, 0), torch.where(wall_b, -2, 1)]))
        merged = net(*batch, torch.where(torch.cat([wall_a, wall_b]), -1, 0))
    assert torch.allclose(both[:offset], alone[0], atol=1e-12)
    assert torch.allclose(both[offset:], alone[1], atol=1e-12)
    assert not torch.allclose(merged[:offset], alone[0], atol=1e-6)


def test_the_processor_refuses_a_missing_context_index():
    net = _network()
    graph, _ = _random_graph(5, 1, 10, 3)
    with pytest.raises(InputError, match="context_index"):
        net(*graph)


def _sim(global_context: bool = True) -> LearnedSimulator:
    torch.manual_seed(11)
    sim = LearnedSimulator(
        HorizontalEquivariantProcessor(
            LATENT, num_steps=2, channels=CHANNELS, wall_sum=True, global_context=global_context
        ),
        radius=0.0075,
        normals="both",
        latent=LATENT,
        dt=0.005,
        contact_feature=True,
        radius_feature=True,
        wall_nodes="patch",
    )
    sim.set_normalization([0.01, -0.02, -0.2], [0.1, 0.12, 0.3], [0.3, 0.1, -9.8], [5.0, 4.0, 8.0])
    return sim.double().eval()


def _acc(sim, scene, seq, t, traj, present):
    props = ParticleProps.of(traj)[present]
    with torch.no_grad():
        return sim.predict_acceleration(seq, WallSet(scene), t, props=props).double()


@pytest.mark.parametrize("kind,frame", [("hopper", 30), ("drum", 40)])
def test_turns_mirrors_shifts_and_remeshing_change_nothing_but_the_frame(kind, frame):
    traj, seq, t, present = _window(kind, frame)
    sim = _sim()
    acc = _acc(sim, traj.scene, seq, t, traj, present)
    scale = float(acc.abs().max())
    frames = (
        horizontal_frame(37.0),
        horizontal_frame(0.0, mirror=True),
        horizontal_frame(211.0, mirror=True),
    )
    for q in frames:
        moved = _acc(sim, turned_scene(traj.scene, q), seq @ q.T, t, traj, present)
        assert torch.allclose(moved, acc @ q.T, atol=1e-5 * scale, rtol=0), q
    finer = _acc(sim, subdivided_scene(traj.scene, 2), seq, t, traj, present)
    assert torch.allclose(finer, acc, atol=1e-5 * scale, rtol=0)
    shift = (0.3, -0.2, 0.1)
    moved_scene = turned_scene(traj.scene, horizontal_frame(0.0), shift)
    shifted = _acc(sim, moved_scene, seq + torch.tensor(shift, dtype=seq.dtype), t, traj, present)
    assert torch.allclose(shifted, acc, atol=1e-5 * scale, rtol=0)


def test_switching_it_on_keeps_the_trained_model_exactly_and_the_mean_is_live():
    plain, pooled = _sim(False), _sim(True)
    state = {f"sim.{k}": v for k, v in plain.state_dict().items()}
    off = {"wall_sum": True, "global_context": False}
    on = {"wall_sum": True, "global_context": True}
    pooled.load_state_dict(
        {k[len("sim.") :]: v for k, v in with_node_inputs(state, LATENT, off, on).items()}
    )
    traj, seq, t, present = _window("hopper", 30)
    a = _acc(plain, traj.scene, seq, t, traj, present)
    b = _acc(pooled, traj.scene, seq, t, traj, present)
    assert torch.equal(a, b)
    with torch.no_grad():  # a weight on the mean moves every particle, near walls or not
        weight = pooled.model.processor.layers[0].node_mlp[0].weight
        weight[:, -LATENT:] = torch.randn(weight.shape[0], LATENT, dtype=weight.dtype)
    c = _acc(pooled, traj.scene, seq, t, traj, present)
    assert ((c - a).abs().amax(dim=1) > 0).all()
    with pytest.raises(InputError, match="global_context"):
        with_node_inputs(state, LATENT, on, off)


def test_the_wall_sum_goes_in_before_an_existing_mean():
    """A model with the mean but not the wall sum, given the wall sum: the mean's columns stay
    the mean's, the new ones are zero, and its function is unchanged."""
    torch.manual_seed(2)
    weight = torch.randn(4, 2 * LATENT + CHANNELS + LATENT)
    state = {
        "sim.model.processor.layers.0.node_mlp.0.weight": weight,
        "sim.model.processor.layers.0.channel_mix.weight": torch.zeros(CHANNELS, CHANNELS),
    }
    before = {"wall_sum": False, "global_context": True}
    on = {"wall_sum": True, "global_context": True}
    out = with_node_inputs(state, LATENT, before, on)
    wide = out["sim.model.processor.layers.0.node_mlp.0.weight"]
    base = 2 * LATENT + CHANNELS
    assert torch.equal(wide[:, :base], weight[:, :base])
    assert torch.equal(wide[:, base : base + LATENT], torch.zeros(4, LATENT))
    assert torch.equal(wide[:, base + LATENT :], weight[:, base:])
    with pytest.raises(InputError, match="input columns"):  # the blocks it claims are not there
        with_node_inputs(state, LATENT, {"wall_sum": True, "global_context": True}, before | on)
