"""`python -m granular_pyg.evaluate`: the rollout's wall time in every evaluation.json, and an
evaluation that starts from the scene alone (the whole job, network alone)."""

from __future__ import annotations

import json
import math

import pytest

from granular_pyg.config import compose
from granular_pyg.evaluate import evaluate


def _evaluate(tmp_path, *extra: str) -> dict:
    cfg = compose(
        "evaluate",
        [
            "ckpt=pretrained:hopper",
            "sample=hopper",
            "max_trajectories=1",
            "threads=1",
            "progress=false",
            "paraview=0",
            f"out={tmp_path}",
            *extra,
        ],
    )
    evaluate(cfg)
    return json.loads((tmp_path / "evaluation.json").read_text())


def test_every_evaluation_records_the_rollouts_wall_time(tmp_path):
    summary = _evaluate(tmp_path, "steps=3")
    row = summary["trajectories"][0]
    assert 0 < row["rollout_wall_s"] < 600
    assert row["rollout_simulated_s"] == pytest.approx(3 * 0.02)
    assert summary["threads"] == 1 and summary["from_scene"] is False
    assert "rollout_wall_s" in (tmp_path / "report.md").read_text()
    assert (tmp_path / "figures" / "test_traj_0003_discharge.png").is_file()


@pytest.mark.slow
def test_an_evaluation_from_the_scene_alone_runs_the_whole_job(tmp_path):
    summary = _evaluate(tmp_path, "from_scene=true", "wall_guard=true")
    row = summary["trajectories"][0]
    assert summary["from_scene"] is True and row["from_scene"] == 1
    # fill and settle (the sample's settle time) plus the recorded half second
    assert row["rollout_simulated_s"] > 0.5
    assert row["position_mse"] is None and row["mixing_entropy_error"] is None  # by index: NaN
    assert row["leaked_particles"] == 0 and row["never_inside_walls"] == 0  # the guard's
    assert math.isfinite(row["discharge_rate_pred"]) and row["discharged_fraction_pred"] > 0.9
    assert (tmp_path / "rollouts" / "test_traj_0003_whole_job.h5").is_file()
