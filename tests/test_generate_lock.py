"""``generate`` shares no folder and keeps its digests (issue 36): a second run into a folder
another run holds is refused in one line (its LIGGGHTS work folders would be shared), and a
resumed run records the SHA-256 of a finished trajectory that a killed run left without one."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time

import pytest

from granular_pyg.errors import InputError
from granular_pyg.generate import _backfill_digests, folder_lock, trajectory_digest
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from tests.test_generate import TINY


def test_a_folder_held_by_another_run_is_refused(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; from pathlib import Path\n"
         "from granular_pyg.generate import folder_lock\n"
         f"with folder_lock(Path({str(tmp_path)!r})):\n"
         "    print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        busy = rf"another generate \(process {holder.pid}\) is "
        with pytest.raises(InputError, match=busy), folder_lock(tmp_path):
            pass
        done = subprocess.run(
            [sys.executable, "-m", "granular_pyg.generate", *TINY, "n=1", f"out={tmp_path}"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
        assert done.returncode == 2 and len(errors) == 1, done.stderr[-2000:]
        assert "another generate" in errors[0] and "out=" in errors[0]
        assert not (tmp_path / "manifest.json").exists() and not (tmp_path / ".work").exists()
    finally:
        holder.kill()
        holder.wait()
    time.sleep(0.1)
    with folder_lock(tmp_path):  # released when its holder ended
        pass


def test_a_resumed_run_backfills_a_missing_digest(tmp_path):
    shutil.copyfile(sample_files("hopper", "test")[0], tmp_path / "traj_0000.h5")
    recorded = {
        "traj_0000.h5": {"file": "traj_0000.h5", "sha256": None},  # killed before the manifest
        "traj_0001.h5": {"file": "traj_0001.h5", "sha256": None},  # not generated yet
    }
    assert _backfill_digests(tmp_path, recorded) == 1
    want = trajectory_digest(read_trajectory(tmp_path / "traj_0000.h5"))
    assert recorded["traj_0000.h5"]["sha256"] == want
    assert recorded["traj_0001.h5"]["sha256"] is None
    assert _backfill_digests(tmp_path, recorded) == 0
    json.dumps(recorded)
