"""Training on the model's own states: the windows' future frames, push-forward's pushed batch,
and the unrolled loss (gradients through the model's run)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hydra.utils import instantiate
from scipy.spatial import cKDTree
from torch_geometric.data import Batch

from granular_pyg.config import compose
from granular_pyg.data.windows import WindowDataset
from granular_pyg.errors import InputError
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet, make_hopper
from granular_pyg.training.data_module import _Collate
from granular_pyg.training.objectives import Mixture, OneStep, PushForward, Unrolled

HISTORY, STEP = 5, 2
GEN = torch.Generator().manual_seed(0)


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "train")[0])


def _base_frames(t: int) -> np.ndarray:
    """The ``H + 2`` frames of the window at ``t``: its inputs and its target."""
    return np.arange(t - HISTORY * STEP, t + 2 * STEP, STEP)


def _window_losing(ds: WindowDataset, hopper, after: int) -> int:
    """Index of the first window with a particle present ``after`` steps after its last input
    frame and gone one step later."""
    for item, (_, t) in enumerate(ds.index):
        keep = hopper.present[_base_frames(t)].all(axis=0)
        there = hopper.present[t + after * STEP] & keep
        if (there & ~hopper.present[t + (after + 1) * STEP]).any():
            return item
    raise AssertionError("no particle leaves the bundled hopper")


def test_future_frames_keep_the_particles_that_leave_as_nan(hopper):
    """Push-forward's future frames do not change a window's particles: one that leaves later
    is NaN there, not dropped from the window."""
    plain = WindowDataset([hopper], HISTORY, STEP)
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=2)
    item = _window_losing(ds, hopper, 1)
    w = ds[item]
    _, t = w.index
    keep = hopper.present[_base_frames(t)].all(axis=0)
    future = torch.from_numpy(hopper.positions[[t + 2 * STEP, t + 3 * STEP]][:, keep])
    torch.testing.assert_close(w.future, future.permute(1, 0, 2), rtol=0, atol=0, equal_nan=True)
    assert bool(torch.isnan(w.future).any())
    same = plain[plain.index.index(w.index)]
    assert torch.equal(w.pos_seq, same.pos_seq) and torch.equal(w.target_pos, same.target_pos)


def _perfect_model(hopper):
    """A small simulator that predicts LIGGGHTS's accelerations (and sends a particle that the
    ground truth loses a metre down, so that it leaves through the outflow there too)."""
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    dt = STEP * hopper.frame_dt
    sim.dt.fill_(dt)
    positions = torch.from_numpy(hopper.positions).double()

    def true_acceleration(pos_seq, walls, time, neighbours=None, ids=None, props=None, frame=None):
        del frame  # the truth's acceleration is in the world frame, as the model's output is
        index = round((time - float(hopper.times[0])) / hopper.frame_dt)
        last, prev = pos_seq[:, -1].double(), pos_seq[:, -2].double()
        here = np.flatnonzero(hopper.present[index])  # the particles, matched by position
        _, nearest = cKDTree(hopper.positions[index, here]).query(last.numpy())
        nxt = positions[index + STEP, here[nearest]]
        gone = torch.isnan(nxt).any(dim=1)
        nxt[gone] = last[gone] - torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        return ((nxt - 2 * last + prev) / dt**2).float()

    sim.predict_acceleration = true_acceleration
    return sim


@pytest.mark.parametrize("unroll", [1, 2])
def test_a_perfect_model_pushed_forward_sees_the_later_ground_truth(hopper, monkeypatch, unroll):
    """With a model that predicts the true accelerations, the pushed batch is the ground truth
    ``unroll`` steps later: the particles still there, their inputs, and their targets (NaN,
    left out of the loss, for those the ground truth loses in the next step)."""
    sim = _perfect_model(hopper)
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=2)
    window = ds[_window_losing(ds, hopper, unroll)]
    _, t = window.index
    keep = np.flatnonzero(hopper.present[_base_frames(t)].all(axis=0))
    pushed = PushForward(max_steps=2).pushed(sim, _Collate(sim, 0.0, 0)([window]), unroll)

    later = t + unroll * STEP
    there = keep[hopper.present[later, keep]]
    seq = torch.from_numpy(hopper.positions[later - HISTORY * STEP : later + 1 : STEP, there])
    seq = seq.permute(1, 0, 2).contiguous()
    expected = sim.build_graph(seq, window.walls, float(hopper.times[later]))
    target = torch.from_numpy(hopper.positions[later + STEP, there])
    expected_y = sim.target_acceleration(seq, target)
    assert pushed.x.shape == expected.x.shape
    assert torch.equal(pushed.edge_index, expected.edge_index)
    torch.testing.assert_close(pushed.x, expected.x, atol=1e-4, rtol=0)
    torch.testing.assert_close(pushed.y, expected_y, atol=1e-3, rtol=0, equal_nan=True)
    lost = torch.isnan(pushed.y).any(dim=1)
    assert 0 < int(lost.sum()) < len(lost)  # some leave in the next step, most stay


@pytest.mark.parametrize("bias", [0.0, 0.3])
def test_the_unrolled_loss_of_a_perfect_model_is_its_bias(hopper, bias):
    """Over 3 steps of its own run, through a window where particles leave, a model that predicts
    LIGGGHTS's accelerations plus ``bias`` m/s^2 downwards has at every step the one-step loss of
    that bias: its run follows the ground truth, correcting what it drifted."""
    sim = _perfect_model(hopper)
    true_acceleration = sim.predict_acceleration
    down = torch.tensor([0.0, 0.0, -bias])
    sim.predict_acceleration = lambda *args, **kw: true_acceleration(*args, **kw) + down
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=2)
    window = ds[_window_losing(ds, hopper, 1)]
    loss = Unrolled(steps=3).loss(sim, _batch_of(sim, window), GEN)
    expected = (bias / float(sim.acc_std[2])) ** 2 / 3
    torch.testing.assert_close(
        loss, torch.tensor(expected, dtype=torch.float32), atol=1e-6, rtol=1e-3
    )


def test_the_unrolled_loss_backpropagates_through_the_run(hopper, monkeypatch):
    """The second step's inputs are the first step's outputs with their gradient; one step is
    the plain one-step loss of the clean window."""
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    sim.dt.fill_(STEP * hopper.frame_dt)
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=1)
    batch = _batch_of(sim, ds[_window_losing(ds, hopper, 1)])
    torch.testing.assert_close(Unrolled(1).loss(sim, batch, GEN), OneStep().loss(sim, batch, GEN))

    seen = []
    build_graph = sim.build_graph
    monkeypatch.setattr(
        sim,
        "build_graph",
        lambda pos_seq, *a, **k: (
            seen.append(pos_seq.requires_grad) or build_graph(pos_seq, *a, **k)
        ),
    )
    loss = Unrolled(steps=2).loss(sim, batch, GEN)
    assert seen == [False, True]
    loss.backward()
    grads = [p.grad for p in sim.parameters() if p.grad is not None]
    assert grads and all(bool(torch.isfinite(g).all()) for g in grads)
    assert any(bool(g.abs().sum() > 0) for g in grads)


def test_the_unrolled_loss_needs_the_future_frames(hopper):
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=1)
    with pytest.raises(InputError, match="steps=3 needs 2 future frames"):
        Unrolled(steps=3).loss(sim, _batch_of(sim, ds[0]), GEN)


def _batch_of(sim, window):
    return _Collate(sim, 0.0, 0)([window])


def test_the_loss_leaves_out_particles_without_a_target():
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    pos = torch.rand(30, HISTORY + 1, 3, dtype=torch.float64) * 0.02
    walls = WallSet(make_hopper())
    graph = sim.build_graph(pos, walls, 0.0)
    graph.y = torch.randn(30, 3)
    full = OneStep().loss(sim, Batch.from_data_list([graph]), GEN)
    graph.y[:10] = float("nan")
    masked = OneStep().loss(sim, Batch.from_data_list([graph]), GEN)
    pred = sim(Batch.from_data_list([graph]))
    assert torch.isfinite(masked)
    torch.testing.assert_close(masked, torch.mean((pred[10:] - graph.y[10:]) ** 2))
    assert not torch.equal(full, masked)
    graph.y[:] = float("nan")
    assert float(OneStep().loss(sim, Batch.from_data_list([graph]), GEN).detach()) == 0.0


def test_the_mixture_gives_each_part_its_share_and_the_rest_one_step():
    """Over many draws each part takes about its share of the batches, in order, and the rest
    take the one-step loss; the same seed draws the same parts (exact resume)."""
    mix = Mixture({"unrolled": Unrolled(4, 0.25), "push_forward": PushForward(3, 0.5)})
    assert mix.future_frames == 3
    g = torch.Generator().manual_seed(1)
    picks = [type(mix.pick(g)).__name__ for _ in range(4000)]
    for name, share in (("Unrolled", 0.25), ("PushForward", 0.5), ("OneStep", 0.25)):
        assert abs(picks.count(name) / 4000 - share) < 0.03
    again = torch.Generator().manual_seed(1)
    assert [type(mix.pick(again)).__name__ for _ in range(50)] == picks[:50]
    assert isinstance(Mixture({}).pick(g), OneStep)


def test_shares_above_one_are_refused():
    with pytest.raises(InputError, match="together at most 1"):
        Mixture({"a": Unrolled(2, 0.7), "b": PushForward(2, 0.5)})


def test_an_experiments_part_settings_under_another_objective_are_named():
    """`+experiment=general_hopper objective=one_step`: the experiment's unrolled settings stay
    without their objective; the error names the part and the override that drops it."""
    from hydra.utils import instantiate

    from granular_pyg.config import compose

    cfg = compose("train", ["+experiment=general_hopper", "objective=one_step"])
    # Hydra wraps the InputError; the command line prints it as one error line
    with pytest.raises(Exception, match=r"objective\.parts\.unrolled.*~objective\.parts\.unrolled"):
        instantiate(cfg.objective)
    fixed = compose(
        "train", ["+experiment=general_hopper", "objective=one_step", "~objective.parts.unrolled"]
    )
    assert isinstance(instantiate(fixed.objective).pick(torch.Generator()), OneStep)
