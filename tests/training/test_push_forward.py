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
from granular_pyg.training import SimulatorModule
from granular_pyg.training.data_module import _Collate

HISTORY, STEP = 5, 2


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

    def true_acceleration(pos_seq, walls, time, neighbours=None, ids=None):
        frame = round((time - float(hopper.times[0])) / hopper.frame_dt)
        last, prev = pos_seq[:, -1].double(), pos_seq[:, -2].double()
        here = np.flatnonzero(hopper.present[frame])  # the particles, matched by position
        _, nearest = cKDTree(hopper.positions[frame, here]).query(last.numpy())
        nxt = positions[frame + STEP, here[nearest]]
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
    monkeypatch.setattr("granular_pyg.training.module.random.randint", lambda a, b: unroll)
    module = SimulatorModule(sim, push_forward_steps=2, push_forward_prob=1.0)
    pushed = module._pushed_forward(_Collate(sim, 0.0, False, 0)([window]))

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
    module = SimulatorModule(sim, unroll_steps=3, unroll_prob=1.0)
    loss = module._unrolled_loss(_batch_of(sim, window))
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
    one = SimulatorModule(sim, unroll_steps=1, unroll_prob=1.0)
    torch.testing.assert_close(one._unrolled_loss(batch), one._loss(batch))

    seen = []
    build_graph = sim.build_graph
    monkeypatch.setattr(
        sim,
        "build_graph",
        lambda pos_seq, *a, **k: (
            seen.append(pos_seq.requires_grad) or build_graph(pos_seq, *a, **k)
        ),
    )
    loss = SimulatorModule(sim, unroll_steps=2, unroll_prob=1.0)._unrolled_loss(batch)
    assert seen == [False, True]
    loss.backward()
    grads = [p.grad for p in sim.parameters() if p.grad is not None]
    assert grads and all(bool(torch.isfinite(g).all()) for g in grads)
    assert any(bool(g.abs().sum() > 0) for g in grads)


def test_one_unrolled_step_from_the_noisy_inputs_is_the_noisy_one_step_loss(hopper):
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    sim.dt.fill_(STEP * hopper.frame_dt)
    window = WindowDataset([hopper], HISTORY, STEP)[3]
    batch = _Collate(sim, 1e-4, True, 0, correct_positions=True)([window])
    noisy = SimulatorModule(sim, unroll_steps=1, unroll_prob=1.0, unroll_noise=True)
    torch.testing.assert_close(noisy._unrolled_loss(batch), noisy._loss(batch))
    clean = SimulatorModule(sim, unroll_steps=1, unroll_prob=1.0)
    assert not torch.allclose(clean._unrolled_loss(batch), noisy._loss(batch))


def test_the_unrolled_loss_needs_the_future_frames(hopper):
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=1)
    module = SimulatorModule(sim, unroll_steps=3, unroll_prob=1.0)
    with pytest.raises(InputError, match="unroll_steps=3 needs 2 future frames"):
        module._unrolled_loss(_batch_of(sim, ds[0]))


def _batch_of(sim, window):
    return _Collate(sim, 0.0, False, 0)([window])


def test_the_loss_leaves_out_particles_without_a_target():
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    module = SimulatorModule(sim)
    pos = torch.rand(30, HISTORY + 1, 3, dtype=torch.float64) * 0.02
    walls = WallSet(make_hopper())
    graph = sim.build_graph(pos, walls, 0.0)
    graph.y = torch.randn(30, 3)
    full = module._loss(Batch.from_data_list([graph]))
    graph.y[:10] = float("nan")
    masked = module._loss(Batch.from_data_list([graph]))
    pred = sim(Batch.from_data_list([graph]))
    assert torch.isfinite(masked)
    torch.testing.assert_close(masked, torch.mean((pred[10:] - graph.y[10:]) ** 2))
    assert not torch.equal(full, masked)
    graph.y[:] = float("nan")
    assert float(module._loss(Batch.from_data_list([graph])).detach()) == 0.0


def test_keep_leaving_holds_the_leavers_with_a_nan_target(hopper):
    """``keep_leaving``: a particle present in the input frames that leaves before the target
    frame stays in the window (NaN target); the others are as in the plain window."""
    plain = WindowDataset([hopper], HISTORY, STEP)
    kept = WindowDataset([hopper], HISTORY, STEP, keep_leaving=True)
    item = next(
        i
        for i, (_, t) in enumerate(kept.index)
        if (hopper.present[_base_frames(t)[:-1]].all(axis=0) & ~hopper.present[t + STEP]).any()
    )
    w = kept[item]
    _, t = w.index
    inputs = hopper.present[_base_frames(t)[:-1]].all(axis=0)
    assert w.pos_seq.shape[0] == int(inputs.sum())
    leaving = torch.from_numpy(~hopper.present[t + STEP][inputs])
    assert bool(leaving.any()) and bool(torch.isnan(w.target_pos[leaving]).all())
    assert bool(torch.isfinite(w.pos_seq).all()) and bool(
        torch.isfinite(w.target_pos[~leaving]).all()
    )
    same = plain[plain.index.index(w.index)]
    torch.testing.assert_close(w.pos_seq[~leaving], same.pos_seq, rtol=0, atol=0)
    assert len(kept) >= len(plain)


def test_keep_leaving_trains_with_a_finite_loss(tmp_path):
    from granular_pyg.train import train

    cfg = compose(
        "train",
        [
            "model.latent=16",
            "data.batch_size=1",
            "trainer.enable_progress_bar=false",
            "data.keep_leaving=true",
            "data.noise_std=1e-5",
            "trainer.fast_dev_run=true",
        ],
    )
    metrics = train(cfg, tmp_path)
    assert torch.isfinite(torch.tensor(metrics["train/loss"]))
