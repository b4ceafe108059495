"""Suite ``scaling``: the fitted exponent and one model-step measurement per precision."""

from __future__ import annotations

import pytest

from granular_pyg.bench.scaling import _exponent, _measure


def test_the_fitted_exponent_of_an_exact_power_law():
    sizes = [1000, 3000, 10000, 100000]
    assert _exponent(sizes, [2e-6 * n**1.1 for n in sizes]) == pytest.approx(1.1, abs=1e-9)


@pytest.mark.parametrize("precision", ["32", "bf16"])
def test_a_model_step_measurement_names_its_precision_and_graph(precision):
    row = _measure("model", 300, 100, 0.0006, 1, precision)
    assert row["precision"] == precision
    assert row["particles"] == 300 and row["edges"] > 300 and row["seconds"] > 0
    assert row["peak_rss_mib"] >= row["extra_rss_mib"] >= 0


def test_model_overrides_change_the_measured_model():
    default = _measure("model", 300, 100, 0.0006, 1)
    narrow = _measure("model", 300, 100, 0.0006, 1, "32", ("model.latent=32",))
    assert narrow["parameters"] < default["parameters"] / 8  # latent 128 -> 32: about 1/16
    assert narrow["edges"] == default["edges"]  # the same graph
