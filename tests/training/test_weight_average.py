"""The weight average (``optim.ema_decay``): exact arithmetic on a tiny module, checkpoints that
hold the average as the model and the raw weights for resume, and an exact resume."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from granular_pyg.errors import InputError
from granular_pyg.inference import load_simulator
from granular_pyg.train import train
from granular_pyg.training.weight_average import WeightAverage
from tests.training.test_train import _steps_cfg, _train_losses


def test_the_average_of_a_tiny_module_is_exact():
    layer = nn.Linear(1, 1, bias=False)
    average = WeightAverage(0.9)
    with torch.no_grad():
        layer.weight.fill_(0.0)
        average.update(layer)  # starts as the weights
        assert average.params["weight"].item() == 0.0
        layer.weight.fill_(1.0)
        average.update(layer)
        assert average.params["weight"].item() == pytest.approx(0.1, abs=1e-7)
        average.update(layer)
        assert average.params["weight"].item() == pytest.approx(0.19, abs=1e-7)
    assert layer.weight.item() == 1.0  # the model's own weights are untouched


@pytest.mark.parametrize("decay", [1.0, -0.5, 1.5])
def test_a_decay_outside_zero_one_is_refused(decay):
    with pytest.raises(InputError, match=r"optim\.ema_decay: expected a number in \(0, 1\)"):
        WeightAverage(decay)


def _weights(ckpt) -> tuple[dict, dict]:
    state = torch.load(ckpt, map_location="cpu", weights_only=True)
    return state["state_dict"], state["raw_weights"]


def test_checkpoints_hold_the_average_and_a_resume_is_exact(tmp_path):
    """The model a checkpoint gives (load_simulator) is the average, not the raw weights; a
    run stopped at step 3 and resumed gives the uninterrupted run's losses, raw weights and
    average at step 6."""
    ema = "optim.ema_decay=0.5"
    train(_steps_cfg(6, ema), tmp_path / "straight")
    train(_steps_cfg(3, ema), tmp_path / "first")
    ckpt = tmp_path / "first" / "checkpoints" / "last.ckpt"
    train(_steps_cfg(6, ema, f"ckpt_path={ckpt}"), tmp_path / "resumed")

    averaged, raw = _weights(ckpt)
    params = [k for k in raw if k.startswith("sim.")]
    assert params and set(raw) <= set(averaged)
    assert any(not torch.equal(averaged[k], raw[k]) for k in params)
    sim, _ = load_simulator(ckpt)
    for key in params:
        assert torch.equal(sim.state_dict()[key[len("sim.") :]], averaged[key])

    straight = _weights(tmp_path / "straight" / "checkpoints" / "last.ckpt")
    resumed = _weights(tmp_path / "resumed" / "checkpoints" / "last.ckpt")
    for a, b in zip(straight, resumed, strict=True):
        for key in params:
            torch.testing.assert_close(a[key], b[key], rtol=1e-6, atol=1e-7)
    losses, again = _train_losses(tmp_path / "straight"), _train_losses(tmp_path / "resumed")
    for step in (s for s in losses if s >= 3):
        assert again[step] == pytest.approx(losses[step], rel=1e-6), step


def test_a_run_without_the_average_resumes_from_the_raw_weights(tmp_path):
    """A checkpoint written with the average, resumed with ema_decay 0: training goes on
    from the raw weights (the losses of the run that kept the average, which does not change
    training itself)."""
    train(_steps_cfg(6, "optim.ema_decay=0.5"), tmp_path / "straight")
    train(_steps_cfg(3, "optim.ema_decay=0.5"), tmp_path / "first")
    ckpt = tmp_path / "first" / "checkpoints" / "last.ckpt"
    train(_steps_cfg(6, f"ckpt_path={ckpt}"), tmp_path / "plain")
    losses, plain = _train_losses(tmp_path / "straight"), _train_losses(tmp_path / "plain")
    for step in (s for s in losses if s >= 3):
        assert plain[step] == pytest.approx(losses[step], rel=1e-6), step


def test_a_rollout_due_by_steps_sees_the_average_and_leaves_training_alone(tmp_path, monkeypatch):
    """A validation rollout in the training loop (``rollout_validation.every_n_steps``) runs
    with the averaged weights, as validation does, and puts the raw weights back: the training
    losses are those of the run without such rollouts."""
    from granular_pyg.training import callbacks

    latest, seen = {}, []
    update, rollout = WeightAverage.update, callbacks.rollout_trajectory

    def recording_update(self, module):
        update(self, module)
        latest.update({k: v.clone() for k, v in self.params.items()})

    def recording_rollout(sim, *args, **kwargs):
        seen.append(({k: p.detach().clone() for k, p in sim.named_parameters()}, dict(latest)))
        return rollout(sim, *args, **kwargs)

    monkeypatch.setattr(WeightAverage, "update", recording_update)
    monkeypatch.setattr(callbacks, "rollout_trajectory", recording_rollout)
    ema = "optim.ema_decay=0.5"
    train(_steps_cfg(4, ema), tmp_path / "plain")
    assert not seen
    steps = ("rollout_validation.every_n_steps=2", "rollout_validation.steps=1")
    train(_steps_cfg(4, ema, *steps), tmp_path / "rollouts")
    assert len(seen) == 2
    for weights, average in seen:
        for name, value in average.items():
            assert torch.equal(weights[name], value), name
    _, raw = _weights(tmp_path / "rollouts" / "checkpoints" / "last.ckpt")
    assert any(not torch.equal(raw[f"sim.{k}"], v) for k, v in seen[-1][1].items())
    plain, rolled = _train_losses(tmp_path / "plain"), _train_losses(tmp_path / "rollouts")
    assert plain and rolled.keys() == plain.keys()
    for step, loss in plain.items():
        assert rolled[step] == pytest.approx(loss, rel=1e-6), step
