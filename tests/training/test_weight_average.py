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
