"""The fine-tuning curve: which trajectories train and which are scored, and a real
one-minute curve on the bundled hopper (fine-tune, resume, evaluate, table and figure)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from granular_pyg.errors import InputError
from granular_pyg.experiments.fine_tune_curve import split_family
from granular_pyg.samples import SAMPLES_DIR


def _family(tmp_path, train: int, test: int):
    splits = {
        "train": [f"t{i}.h5" for i in range(train)],
        "valid": ["v.h5"],
        "test": [f"s{i}.h5" for i in range(test)],
    }
    (tmp_path / "manifest.json").write_text(json.dumps({"splits": splits}))
    return tmp_path


def test_runs_train_on_the_first_trajectories_and_the_rest_is_scored(tmp_path):
    pool, valid, scored = split_family(_family(tmp_path, 10, 1), largest=5)
    assert [p.name for p in pool] == ["t0.h5", "t1.h5", "t2.h5", "t3.h5", "t4.h5"]
    assert [p.name for p in valid] == ["v.h5"]
    assert [p.name for p in scored] == ["s0.h5", "t5.h5", "t6.h5", "t7.h5", "t8.h5", "t9.h5"]
    assert not set(pool) & set(scored)


def test_a_family_too_small_for_the_largest_run_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"--new: .* 3 training trajectories, fewer than 5"):
        split_family(_family(tmp_path, 3, 1), largest=5)
    with pytest.raises(InputError, match="no trajectory to score"):
        split_family(_family(tmp_path, 5, 0), largest=5)


@pytest.mark.slow
def test_a_one_minute_curve_on_the_bundled_hopper(tmp_path):
    out = tmp_path / "curve"
    cmd = [
        sys.executable,
        "-m",
        "granular_pyg.experiments.fine_tune_curve",
        "--family",
        str(SAMPLES_DIR / "hopper"),
        "--new",
        "1",
        "--minutes",
        "1",
        "--out",
        str(out),
        "trainer.enable_progress_bar=false",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    curve = json.loads((out / "curve.json").read_text())
    # scored: the test hopper and the second training hopper, never the one it trained on
    assert [p.rsplit("/", 1)[-1] for p in curve["scored"]] == ["traj_0003.h5", "traj_0001.h5"]
    initial, tuned = curve["points"]
    assert (initial["new"], initial["minutes"], tuned["new"], tuned["minutes"]) == (0, 0, 1, 1)
    assert 0 <= tuned["discharge_rate_abs_error_mean"] <= tuned["discharge_rate_abs_error_worst"]
    assert (out / "new1" / "at_1min.ckpt").is_file() and (out / "curve.png").stat().st_size > 0
    assert tuned["steps"] > 0 and f"| 1 | 1 | {tuned['steps']} |" in (out / "curve.md").read_text()
    # a second call reads the finished points back instead of training again
    again = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "granular_pyg.train" not in again.stdout
