"""Stress rollouts: every step checked; NaN, energy growth and leaks reported at their step."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from granular_pyg.config import compose
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.stress import kinetic_energy, stress, stress_case
from granular_pyg.train import train


def _model(radius: float = 0.0075, acc_mean=(0.0, 0.0, -9.8), k: int = 2) -> LearnedSimulator:
    torch.manual_seed(0)
    sim = LearnedSimulator(Processor(latent=16, num_steps=2), radius=radius, latent=16)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], list(acc_mean), [1e-3, 1e-3, 1e-3])
    sim.dt.fill_(k * 0.0025)
    return sim.eval()


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


def test_kinetic_energy_of_two_particles_ignores_those_that_left():
    prev = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [float("nan")] * 3])
    nxt = torch.tensor([[0.1, 0.0, 0.0], [1.0, 0.0, -0.2], [0.0, 0.0, 0.0]])
    mass = torch.tensor([2.0, 1.0, 5.0], dtype=torch.float64)
    # v = 1 and 2 m/s over dt = 0.1 s: 0.5 * 2 * 1 + 0.5 * 1 * 4 = 3 J
    assert kinetic_energy(prev, nxt, mass, 0.1) == pytest.approx(3.0)


def test_discharging_hopper_reports_outflow_without_drift_and_a_sane_energy(hopper):
    summary, rows = stress_case(_model(), hopper, 14, sample_every=3, progress=False)
    assert summary["steps_done"] == 14 and summary["drift"] == 0
    # every step up to 3^2, then every third, and the last
    assert [r["step"] for r in rows] == [*range(9), 9, 12, 13]
    assert rows[-1]["present"] == hopper.num_particles - summary["left_through_outflow"]
    assert all(np.isfinite(r["divergence_m"]) for r in rows)
    assert summary["max_divergence_m"] < 1e-4  # float32 against float64 over 14 steps


def test_a_nan_prediction_is_the_first_failure_at_its_step(hopper):
    sim = _model()
    real, calls = sim.predict_acceleration, {"n": 0}

    def nan_on_fourth_call(seq, *args, **kwargs):
        acc = real(seq, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 4:
            acc[5] = float("inf")
        return acc

    sim.predict_acceleration = nan_on_fourth_call
    summary, _ = stress_case(sim, hopper, 10, compare_float64=False, progress=False)
    assert summary["first_failure_step"] == 3 and summary["steps_done"] == 3
    assert "NaN/Inf" in summary["failure"] and "[5]" in summary["failure"]


def test_energy_growth_is_reported(hopper):
    # A model that always predicts 200 m/s^2 upwards.
    summary, _ = stress_case(
        _model(acc_mean=(0.0, 0.0, 200.0)), hopper, 8, compare_float64=False, progress=False
    )
    assert "kinetic energy" in summary["failure"] and summary["max_kinetic_energy_ratio"] > 10


def _pushed_through_the_lid(hopper, wall_guard: bool) -> dict:
    """A resting bed under 100 g (a model that always predicts -980 m/s^2), lid kept closed."""
    summary, _ = stress_case(
        _model(acc_mean=(0.0, 0.0, -980.0)),
        hopper,
        6,
        resting=True,
        compare_float64=False,
        ke_limit=1e12,
        progress=False,
        wall_guard=wall_guard,
    )
    return summary


def test_resting_hopper_pushed_through_its_lid_is_a_leak(hopper):
    summary = _pushed_through_the_lid(hopper, wall_guard=False)
    assert "leaked" in summary["failure"] and summary["leaked_particles"] > 0


def test_the_wall_guard_holds_the_bed_a_model_pushes_through_its_lid(hopper):
    """The same push with the wall guard: nothing leaks, the lid takes it, and the bed pressed
    into the lid is reported crushed, where the case stops."""
    summary = _pushed_through_the_lid(hopper, wall_guard=True)
    assert summary["leaked_particles"] == 0 and summary["wall_guard"] is True
    assert summary["wall_guard_corrections"] > 100
    assert "crushed bed" in summary["failure"]
    assert summary["first_failure_step"] < summary["steps_done"] < 6
    assert summary["max_overlapping_particles"] > 0.5 * 948


def test_drum_keeps_every_particle():
    drum = read_trajectory(sample_files("drum", "test")[0])
    summary, rows = stress_case(_model(radius=0.01, k=2), drum, 6, progress=False)
    assert summary["drift"] == 0 and summary["left_through_outflow"] == 0
    assert rows[-1]["present"] == drum.num_particles


@pytest.mark.slow
def test_stress_command_quick_mode_writes_its_report(tmp_path):
    run = tmp_path / "run"
    train(
        compose(
            "train",
            [
                "model.latent=16",
                "data.batch_size=1",
                "data.frames_per_step=4",
                "trainer.enable_progress_bar=false",
                "trainer.max_steps=1",
                "data.train_samples_per_epoch=1",
                "data.val_samples=1",
                "rollout_validation.every_n_epochs=1000",
            ],
        ),
        run,
    )
    ckpt = run / "checkpoints" / "last.ckpt"
    cfg = compose(
        "stress",
        [
            "quick=true",
            "quick_steps=5",
            "progress=false",
            "~cases.drum",
            "~cases.drum_precision",
            f"cases.hopper_resting.ckpt={ckpt}",
            f"cases.hopper_discharging.ckpt={ckpt}",
        ],
    )
    summaries = stress(cfg, tmp_path / "out")
    assert set(summaries) == {"hopper_resting", "hopper_discharging"}
    saved = json.loads((tmp_path / "out" / "stress.json").read_text())
    assert saved["hopper_discharging"]["steps"] == 5
    assert (tmp_path / "out" / "stress.png").stat().st_size > 0
    assert "| hopper_resting |" in (tmp_path / "out" / "stress.md").read_text()


def test_a_particle_flung_out_of_the_drum_escapes_the_box_and_the_run_goes_on():
    # Particle 7 gets 1e6 m/s^2 along +x on the second step: it leaves the drum's box within
    # one step; it is removed as LIGGGHTS would (never reaching coordinates float32 cannot
    # resolve) and reported, and the other particles roll on.
    drum = read_trajectory(sample_files("drum", "test")[0])
    sim = _model(radius=0.01, k=2)
    real, calls = sim.predict_acceleration, {"n": 0}

    def fling_on_second_call(seq, *args, **kwargs):
        acc = real(seq, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 2:
            acc[7, 0] = 1e6
        return acc

    sim.predict_acceleration = fling_on_second_call
    summary, rows = stress_case(sim, drum, 4, compare_float64=False, progress=False)
    assert summary["steps_done"] == 4 and summary["escaped_box"] == 1 and summary["drift"] == 0
    assert summary["first_failure_step"] == 1 and "escaped" in summary["failure"]
    assert summary["leaked_particles"] >= 1
    assert rows[-1]["present"] == drum.num_particles - 1
