"""``objective=bulk_motion``: the one-step loss plus the error of each horizontal layer's mean
acceleration (the bed's collective motion)."""

from __future__ import annotations

import math

import pytest
import torch

from granular_pyg.errors import InputError
from granular_pyg.training.objectives import BulkMotion, Mixture, OneStep
from granular_pyg.training.objectives.bulk_motion import layer_mean_error
from tests.training.one_batch import model_objective_batch


def _brute_force(pred, target, height, graph, layer):
    """The layer term by loops over graphs and layers, for comparison."""
    cells = {}
    for i in range(len(pred)):
        if not torch.isfinite(target[i]).all():
            continue
        g = int(graph[i])
        known = torch.isfinite(target).all(dim=1) & (graph == g)
        lowest = float(height[known].min())
        key = (g, math.floor((float(height[i]) - lowest) / layer))
        cells.setdefault(key, []).append(pred[i] - target[i])
    means = [torch.stack(rows).mean(dim=0) for rows in cells.values()]
    return (torch.stack(means) ** 2).mean()


def test_layer_means_tiny_case():
    # graph 0: two particles in its lowest 10 mm layer, one in the next; graph 1: one layer
    height = torch.tensor([0.200, 0.205, 0.215, 1.000, 1.002])
    graph = torch.tensor([0, 0, 0, 1, 1])
    target = torch.zeros(5, 3)
    pred = torch.zeros(5, 3)
    pred[0, 2], pred[1, 2] = 1.0, 3.0  # layer mean error (0, 0, 2)
    pred[2, 0] = -1.0  # layer mean error (-1, 0, 0)
    pred[3, 1], pred[4, 1] = 2.0, -2.0  # they cancel: (0, 0, 0)
    # squares 4, 1, 0 over 3 layers and 3 components
    torch.testing.assert_close(
        layer_mean_error(pred, target, height, graph, 0.01), torch.tensor(5.0 / 9.0)
    )


def test_a_shared_offset_counts_fully_and_scatter_cancels():
    torch.manual_seed(0)
    height, graph = torch.rand(200) * 0.1, torch.randint(0, 3, (200,))
    target = torch.randn(200, 3)
    offset = torch.tensor([0.1, -0.2, 0.3])
    torch.testing.assert_close(
        layer_mean_error(target + offset, target, height, graph, 0.02), (offset**2).mean()
    )
    # one particle of a pair above the other by +e, the other by -e, both in one layer
    pair = torch.tensor([[1.0, 0, 0], [-1.0, 0, 0]])
    one_layer = torch.zeros(2).long()
    assert layer_mean_error(pair, torch.zeros(2, 3), torch.zeros(2), one_layer, 0.01) == 0


def test_layer_means_against_brute_force_and_unchanged_by_turns_mirrors_and_shifts():
    torch.manual_seed(1)
    for _ in range(5):
        n = 120
        pred = torch.randn(n, 3, dtype=torch.float64)
        target = torch.randn(n, 3, dtype=torch.float64)
        target[torch.randperm(n)[:10], 1] = float("nan")  # particles the ground truth has lost
        height = torch.rand(n, dtype=torch.float64) * 0.08 + 0.3
        graph = torch.randint(0, 4, (n,))
        value = layer_mean_error(pred, target, height, graph, 0.013)
        torch.testing.assert_close(value, _brute_force(pred, target, height, graph, 0.013))
        angle = float(torch.rand(1)) * 2 * math.pi
        c, s = math.cos(angle), math.sin(angle)
        turn = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
        mirror = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
        for q in (turn, mirror @ turn):
            turned = layer_mean_error(pred @ q.T, target @ q.T, height, graph, 0.013)
            torch.testing.assert_close(turned, value)
        shift = torch.rand(4, dtype=torch.float64)[graph]  # each graph moved up its own way
        torch.testing.assert_close(
            layer_mean_error(pred, target, height + shift, graph, 0.013), value
        )


def test_no_known_target_gives_a_zero_that_keeps_the_graph():
    pred = torch.ones(3, 3, requires_grad=True)
    target = torch.full((3, 3), float("nan"))
    loss = layer_mean_error(pred, target, torch.zeros(3), torch.zeros(3).long(), 0.01)
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.equal(pred.grad, torch.zeros(3, 3))


def test_bad_settings_are_named():
    with pytest.raises(InputError, match=r"bulk_motion\.layer"):
        BulkMotion(layer=0.0)
    with pytest.raises(InputError, match=r"bulk_motion\.weight"):
        BulkMotion(weight=-1.0)


def test_the_objective_is_one_step_plus_the_weighted_layer_term_on_a_real_batch():
    torch.manual_seed(0)
    sim, objective, batch = model_objective_batch(
        ["model.latent=16", "data.batch_size=2", "objective=bulk_motion"]
    )
    assert isinstance(objective, Mixture)
    part = objective.parts["bulk_motion"]
    assert isinstance(part, BulkMotion) and part.share == 1.0
    with torch.no_grad():
        one_step = OneStep().loss(sim, batch, None)
        pred = sim(batch)
        real = ~batch.is_wall
        layers = layer_mean_error(pred, batch.y, batch.pos[real, 2], batch.batch[real], part.layer)
        torch.testing.assert_close(BulkMotion(weight=0.0).loss(sim, batch, None), one_step)
        torch.testing.assert_close(
            objective.loss(sim, batch, torch.Generator().manual_seed(0)),
            one_step + part.weight * layers,
        )
    assert int(batch.batch[real].max()) == 1 and float(layers) > 0
    loss = part.loss(sim, batch, None)
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in sim.parameters() if p.grad is not None)
