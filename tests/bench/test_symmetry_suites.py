"""Suites invariance and rest: they score each variant against its own transformed truth and
judge the targets; a model that is equivariant by construction passes the turns and mirrors."""

from __future__ import annotations

import numpy as np
import pytest

from granular_pyg.bench.invariance import run as run_invariance
from granular_pyg.bench.rest import run as run_rest


@pytest.mark.parametrize("model", ["pretrained:fast_drum"])
def test_invariance_suite_scores_every_variant(model):
    result = run_invariance(
        (model,), ("sample:drum",), variants=("turn_90", "remesh_x4"), steps=3, seed=0
    )
    assert [r["variant"] for r in result.rows] == ["original", "turn_90", "remesh_x4"]
    assert all(np.isfinite(r["emd_mean"]) for r in result.rows)
    names = [t.name for t in result.targets]
    assert any("turn_90: |angle error change|" in n for n in names)
    assert f"{model}/spread/emd_mean" in result.results


def test_rest_suite_reports_drift_and_leaks():
    result = run_rest(("pretrained:fast_hopper",), ("sample:hopper",), duration=0.2)
    (row,) = result.rows
    assert row["seconds"] == pytest.approx(0.2, abs=0.05)
    assert row["mean_drift_mm"] >= 0 and row["max_drift_mm"] >= row["mean_drift_mm"]
    assert len(result.targets) == 3
