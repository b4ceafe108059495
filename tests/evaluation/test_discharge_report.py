"""A hopper's evaluation: discharge against the initial bed, discharged fraction and time to
empty on both sides, Beverloo's rate, the discharge figure in the report, and frame
invariance of all of it."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from granular_pyg.evaluation import evaluate_pair, write_evaluation
from granular_pyg.evaluation.report import EvaluatedRollout
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files

DISCHARGE = (
    "discharge_rate_truth",
    "discharge_rate_pred",
    "discharge_rate_rel_error",
    "discharged_fraction_truth",
    "discharged_fraction_pred",
    "discharged_fraction_error",
    "time_to_empty_truth_s",
    "time_to_empty_pred_s",
    "beverloo_rate",
)


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


def _as_rollout(truth, k: int = 2, history: int = 5, frames: int = 100):
    idx = np.arange(0, k * frames, k)
    idx = idx[idx < truth.num_frames]
    return dataclasses.replace(
        truth,
        positions=truth.positions[idx],
        velocities=truth.velocities[idx],
        times=truth.times[idx],
        metadata={"initial_frames": history + 1, "frames_per_step": k},
    )


def test_a_perfect_rollout_discharges_like_the_truth(hopper):
    s = evaluate_pair(hopper, _as_rollout(hopper)).scalars
    assert s["discharged_fraction_truth"] == s["discharged_fraction_pred"] > 0.99
    assert s["discharged_fraction_error"] == 0 and s["discharge_rate_rel_error"] == 0
    assert s["time_to_empty_truth_s"] == s["time_to_empty_pred_s"] > 0
    assert 0.5 < s["discharge_rate_truth"] / s["beverloo_rate"] < 2.0


def test_a_rollout_that_keeps_part_of_its_bed_shows_it(hopper):
    """The rollout lets out the particles of the truth, but a fifth of them (the lowest ids)
    never leave: its final fraction is 20 points short, it never empties, and its rate (fitted
    against the initial bed) is lower than the truth's."""
    pred = _as_rollout(hopper)
    pred.positions = pred.positions.copy()
    stuck = np.arange(hopper.num_particles // 5)
    pred.positions[:, stuck] = pred.positions[:1, stuck]
    s = evaluate_pair(hopper, pred).scalars
    short = -len(stuck) / hopper.num_particles
    assert s["discharged_fraction_error"] == pytest.approx(short, abs=0.01)
    assert math.isnan(s["time_to_empty_pred_s"]) and s["time_to_empty_truth_s"] > 0
    assert s["discharge_rate_pred"] < s["discharge_rate_truth"]


@pytest.mark.parametrize("angle", [0.7, 2.9])
def test_the_discharge_scalars_do_not_depend_on_the_frame(hopper, angle):
    """The scene, truth and rollout turned about gravity (z), and mirrored: the same numbers."""
    pred = _as_rollout(hopper)
    pred.positions = pred.positions.copy()
    pred.positions[6:, ::3, 2] += np.float32(0.003)  # some disagreement to measure
    c, s = math.cos(angle), math.sin(angle)
    for frame in (np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), np.diag([-1.0, 1.0, 1.0])):
        moved_truth, moved_pred = (_moved(t, frame) for t in (hopper, pred))
        a = evaluate_pair(hopper, pred).scalars
        b = evaluate_pair(moved_truth, moved_pred).scalars
        for key in DISCHARGE:
            assert b[key] == pytest.approx(a[key], rel=1e-6, nan_ok=True), key


def _moved(traj, frame: np.ndarray):
    scene = traj.scene
    walls = [dataclasses.replace(w, vertices=w.vertices @ frame.T) for w in scene.walls]
    corners = np.array([scene.domain_lo, scene.domain_hi]) @ frame.T
    moved_scene = dataclasses.replace(
        scene,
        walls=walls,
        domain_lo=tuple(corners.min(0)),
        domain_hi=tuple(corners.max(0)),
    )
    return dataclasses.replace(
        traj,
        positions=(traj.positions @ frame.T).astype(traj.positions.dtype),
        velocities=(traj.velocities @ frame.T).astype(traj.velocities.dtype),
        scene=moved_scene,
    )


def test_every_hopper_report_has_its_discharge_curve_and_the_new_scalars(tmp_path, hopper):
    ev = evaluate_pair(hopper, _as_rollout(hopper))
    ev.scalars["rollout_wall_s"] = 1.25
    rollouts = [EvaluatedRollout("test", "traj_0003.h5", "truth.h5", "pred.h5", ev)]
    report = write_evaluation(tmp_path, rollouts, {"variant": "V3", "ckpt": "x.ckpt"})
    text = report.read_text()
    assert "figures/test_traj_0003_discharge.png" in text
    for key in ("discharged_fraction_truth", "time_to_empty_pred_s", "beverloo_rate"):
        assert f"| {key} |" in text
    png = tmp_path / "figures" / "test_traj_0003_discharge.png"
    assert png.read_bytes()[:4] == b"\x89PNG"
    summary = json.loads((tmp_path / "evaluation.json").read_text())
    row = summary["trajectories"][0]
    assert row["rollout_wall_s"] == 1.25 and summary["means"]["test"]["rollout_wall_s"] == 1.25
    assert row["discharged_fraction_pred"] == row["discharged_fraction_truth"] > 0.99
