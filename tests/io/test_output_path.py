"""Nothing of the user's is overwritten: outputs are checked before the work starts."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from granular_pyg.errors import InputError, whole_number
from granular_pyg.io import check_output
from granular_pyg.samples import sample_files


def test_an_output_that_is_an_input_is_refused(tmp_path):
    source = tmp_path / "run.h5"
    source.write_bytes(b"data")
    link = tmp_path / "link.h5"
    link.symlink_to(source)
    for out in (source, link, tmp_path / "." / "run.h5"):
        with pytest.raises(InputError, match="is the input"):
            check_output(out, [source])
    dumps = tmp_path / "dumps"
    dumps.mkdir()
    with pytest.raises(InputError, match="is the input"):
        check_output(dumps / "traj.h5", [dumps], option="--out")
    assert source.read_bytes() == b"data"


def test_an_existing_output_needs_overwrite(tmp_path):
    out = tmp_path / "result.h5"
    out.write_bytes(b"old")
    with pytest.raises(InputError, match=r"exists; .* overwrite=true"):
        check_output(out)
    assert check_output(out, overwrite=True) == out
    with pytest.raises(InputError, match="is a folder"):
        check_output(tmp_path)


def test_an_unwritable_or_full_folder_is_refused_before_the_work(tmp_path):
    if os.geteuid() == 0:  # root writes anywhere; the free-space rule is tested instead
        with pytest.raises(InputError, match="MiB free"):
            check_output(tmp_path / "x.h5", min_free_bytes=shutil.disk_usage(tmp_path).total * 2)
        return
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    with pytest.raises(InputError, match="not writable"):
        check_output(locked / "x.h5")


def test_whole_numbers():
    assert whole_number("steps", 3) == 3 and whole_number("steps", 1e3) == 1000
    for bad in (2.7, "abc", -1, True, None):
        with pytest.raises(InputError, match="steps: expected a whole number"):
            whole_number("steps", bad)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["out=truth.h5"], "is the input"),
        (["out=existing.h5"], "exists"),
        (["steps=2.7"], "whole number"),
        (["steps=abc"], "whole number"),
        (["steps=1e12"], "GiB"),
    ],
)
def test_rollout_refuses_before_computing_and_keeps_the_inputs(tmp_path, args, message):
    truth = tmp_path / "truth.h5"
    shutil.copy(sample_files("hopper", "test")[0], truth)
    (tmp_path / "existing.h5").write_bytes(b"earlier result")
    before = {p.name: _digest(p) for p in tmp_path.glob("*.h5")}
    done = subprocess.run(
        [sys.executable, "-m", "granular_pyg.rollout", "ckpt=pretrained:hopper",
         "trajectory=truth.h5", *args],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2 and message in done.stderr, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert {p.name: _digest(p) for p in tmp_path.glob("*.h5")} == before


def test_a_failed_write_keeps_the_rollout_in_a_named_fallback(tmp_path, monkeypatch):
    from granular_pyg import rollout as rollout_module
    from granular_pyg.io import Trajectory, read_trajectory

    real = rollout_module.write_trajectory
    out = tmp_path / "out" / "pred.h5"

    def full_disk(traj: Trajectory, path):
        if Path(path) == out:
            raise OSError(28, "No space left on device")
        real(traj, path)

    monkeypatch.setattr(rollout_module, "write_trajectory", full_disk)
    traj = read_trajectory(sample_files("hopper", "test")[0])
    with pytest.raises(InputError, match=r"kept in (\S+\.h5)") as info:
        rollout_module._write_or_keep(traj, out)
    fallback = Path(str(info.value).rsplit(" ", 1)[-1])
    assert read_trajectory(fallback).num_frames == traj.num_frames
    fallback.unlink()
