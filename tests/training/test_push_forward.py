"""Push-forward training: the windows' future frames, and the pushed batch's inputs and targets."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from granular_pyg.config import compose
from granular_pyg.data.windows import WindowDataset
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.training import SimulatorModule
from granular_pyg.training.data_module import _Collate

HISTORY, STEP = 5, 2


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "train")[0])


def _frames(t: int, extra: int) -> np.ndarray:
    return np.arange(t - HISTORY * STEP, t + (2 + extra) * STEP, STEP)


def test_windows_keep_the_future_frames_of_their_particles(hopper):
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=2)
    w = ds[len(ds) // 2]
    _, t = w.index
    keep = hopper.present[_frames(t, 2)].all(axis=0)
    future = hopper.positions[[t + 2 * STEP, t + 3 * STEP]][:, keep]
    assert torch.equal(w.future, torch.from_numpy(future).permute(1, 0, 2))
    assert torch.equal(w.target_pos, torch.from_numpy(hopper.positions[t + STEP][keep]))
    assert w.pos_seq.shape[0] == int(keep.sum())


@pytest.mark.parametrize("unroll", [1, 2])
def test_a_perfect_model_pushed_forward_sees_the_later_ground_truth(hopper, monkeypatch, unroll):
    """With a model that predicts the true accelerations, the pushed batch is exactly the
    ground-truth window ``unroll`` steps later: its inputs and its target."""
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    dt = STEP * hopper.frame_dt
    sim.dt.fill_(dt)
    ds = WindowDataset([hopper], HISTORY, STEP, extra_steps=2)
    window = ds[len(ds) // 2]
    _, t = window.index
    keep = hopper.present[_frames(t, 2)].all(axis=0)
    positions = torch.from_numpy(hopper.positions[:, keep]).double()

    def true_acceleration(pos_seq, walls, time, neighbours=None, ids=None):
        frame = round((time - float(hopper.times[0])) / hopper.frame_dt)
        last, prev = pos_seq[:, -1].double(), pos_seq[:, -2].double()
        return ((positions[frame + STEP] - 2 * last + prev) / dt**2).float()

    monkeypatch.setattr(sim, "predict_acceleration", true_acceleration)
    monkeypatch.setattr("granular_pyg.training.module.random.randint", lambda a, b: unroll)
    module = SimulatorModule(sim, push_forward_steps=2, push_forward_prob=1.0)
    pushed = module._pushed_forward(_Collate(sim, 0.0, False, 0)([window]))

    later = t + unroll * STEP
    seq = positions[np.arange(later - HISTORY * STEP, later + 1, STEP)].permute(1, 0, 2).float()
    expected = sim.build_graph(seq, window.walls, float(hopper.times[later]))
    expected_y = sim.target_acceleration(seq, positions[later + STEP].float())
    assert torch.equal(pushed.edge_index, expected.edge_index)
    torch.testing.assert_close(pushed.x, expected.x, atol=1e-4, rtol=0)
    torch.testing.assert_close(pushed.y, expected_y, atol=1e-3, rtol=0)
    # and differs from the window's own, unpushed target: the later step is a different one
    plain = _Collate(sim, 0.0, False, 0)([window])
    assert not torch.allclose(pushed.y, plain.y, atol=1e-2)
