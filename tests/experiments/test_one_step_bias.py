"""One-step bias by height: exact for a perfect and an offset model, the CLI's files, bad bands."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.experiments.one_step_bias import format_table, one_step_bias
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files

REPO = Path(__file__).resolve().parents[2]
BANDS = [(0.02, 1.0), (0.0, 0.02), (-1.0, 0.0)]
STEP = 4


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


def _sim(hopper, offset: float | None):
    """A small simulator whose prediction is the true acceleration (+ ``offset`` in z), or the
    untrained network for ``offset=None``."""
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    dt = STEP * hopper.frame_dt
    sim.dt.fill_(dt)
    if offset is None:
        return sim
    t0, positions = float(hopper.times[0]), torch.from_numpy(hopper.positions).double()
    ids = {}

    def true_acceleration(pos_seq, walls, time, neighbours=None, ids_=None, props=None):
        frame = round((time - t0) / hopper.frame_dt)
        rows = ids[frame]
        acc = (positions[frame + STEP, rows] - 2 * pos_seq[:, -1] + pos_seq[:, -2]) / dt**2
        return (acc + torch.tensor([0.0, 0.0, offset], dtype=torch.float64)).float()

    for t in range(hopper.num_frames - STEP):  # each window's particles, as the tool keeps them
        frames = np.arange(t - sim.history * STEP, t + STEP + 1, STEP)
        if frames[0] >= 0:
            ids[t] = torch.from_numpy(np.flatnonzero(hopper.present[frames].all(axis=0)))
    sim.predict_acceleration = true_acceleration
    return sim


@pytest.mark.parametrize("offset", [0.0, 1.5])
def test_a_perfect_model_has_no_bias_and_an_offset_one_its_offset(hopper, offset):
    rows = one_step_bias(_sim(hopper, offset), [hopper], BANDS)
    windows = range(5 * STEP, hopper.num_frames - STEP, STEP)
    expected = sum(
        int(hopper.present[np.arange(t - 5 * STEP, t + STEP + 1, STEP)].all(axis=0).sum())
        for t in windows
    )
    assert sum(r["count"] for r in rows) == expected  # the bands cover every height once
    for row in rows:
        if row["count"]:
            assert row["bias"] == pytest.approx(offset, abs=1e-3)
            assert row["rmse"] == pytest.approx(offset, abs=1e-3)
            assert row["pred_az"] == pytest.approx(row["true_az"] + offset, abs=1e-3)
    assert rows[0]["count"] > 0 and rows[1]["count"] > 0  # the bed and the outlet region


def test_last_time_and_every_thin_the_windows(hopper):
    sim = _sim(hopper, 0.0)
    every = one_step_bias(sim, [hopper], BANDS)
    assert sum(r["count"] for r in one_step_bias(sim, [hopper], BANDS, every=2)) < sum(
        r["count"] for r in every
    )
    early = one_step_bias(sim, [hopper], BANDS, last_time=float(hopper.times[8 * STEP]))
    assert 0 < sum(r["count"] for r in early) < sum(r["count"] for r in every)


def test_an_empty_band_is_nan_and_the_table_shows_it(hopper):
    rows = one_step_bias(_sim(hopper, 0.0), [hopper], [(5.0, 6.0)])
    assert rows[0]["count"] == 0 and np.isnan(rows[0]["bias"])
    assert "| 5000 to 6000 | 0 | nan |" in format_table(rows)


@pytest.mark.parametrize("bands", [[], [(0.01, 0.0)]])
def test_bad_bands_name_the_fix(hopper, bands):
    with pytest.raises(InputError, match="bands: expected"):
        one_step_bias(_sim(hopper, None), [hopper], bands)


def test_the_command_writes_the_table_for_a_pretrained_model(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "granular_pyg.experiments.one_step_bias",
        "ckpt=pretrained:hopper",
        f"files=[{sample_files('hopper', 'test')[0]}]",
        "every=4",
        f"out={tmp_path}",
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((tmp_path / "results.json").read_text())
    assert len(results["rows"]) == 5 and sum(r["count"] for r in results["rows"]) > 0
    assert "| particle-windows |" in (tmp_path / "table.md").read_text()
    assert "granular_pyg.experiments.one_step_bias ckpt=pretrained:hopper" in results["command"]


def test_time_bands_split_each_height_band_by_the_time_since_the_lid_went(hopper):
    sim = _sim(hopper, 1.5)
    whole = one_step_bias(sim, [hopper], BANDS)
    times = [(-1.0, 0.05), (0.05, 0.1), (0.1, 10.0)]  # the lid goes at 0.02 s
    split = one_step_bias(sim, [hopper], BANDS, times=times)
    assert [(r["z_low"], r["t_low"]) for r in split] == [(b[0], t[0]) for b in BANDS for t in times]
    for b, row in enumerate(whole):  # the time bands partition each height band's windows
        assert sum(r["count"] for r in split[3 * b : 3 * b + 3]) == row["count"]
    assert split[0]["count"] > 0 and split[2]["count"] > 0  # the bed early and late
    assert all(r["bias"] == pytest.approx(1.5, abs=1e-3) for r in split if r["count"])
    assert "| 20 to 1000 | -1 to 0.05 |" in format_table(split)
    assert whole[0]["t_low"] is None  # plain JSON in results.json
    assert "after the outlet opens" not in format_table(whole)


def test_time_bands_need_a_scene_whose_outlet_opens(hopper):
    closed = dataclasses.replace(hopper, scene=None)
    with pytest.raises(InputError, match="times: trajectory 0 has no wall removed"):
        one_step_bias(_sim(hopper, None), [closed], BANDS, times=[(0.0, 1.0)])
    with pytest.raises(InputError, match="times: expected"):
        one_step_bias(_sim(hopper, None), [hopper], BANDS, times=[(1.0, 0.0)])
