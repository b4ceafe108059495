"""Every command's error style: bad input is one ``error:`` line and exit status 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from granular_pyg.cli import EXIT_INPUT_ERROR, reports_errors
from granular_pyg.errors import InputError

# (module, arguments, a word the message must contain)
CASES = [
    ("granular_pyg.train", ["data.sample=null"], "data.root"),
    ("granular_pyg.rollout", ["ckpt=missing.ckpt"], "missing.ckpt"),
    ("granular_pyg.evaluate", ["ckpt=missing.ckpt"], "missing.ckpt"),
    ("granular_pyg.generate", ["+scene.ranges.colour=[1,2]", "out=data/x"], "colour"),
    ("granular_pyg.compare", ["runs=[missing_folder]"], "missing_folder"),
    ("granular_pyg.stress", ["cases.hopper_resting.ckpt=missing.ckpt"], "missing.ckpt"),
    ("granular_pyg.bench", ["suite=rollout_speed", "suite.run.ckpts=[missing.ckpt]"], "missing"),
    ("granular_pyg.experiments.one_step_bias", ["ckpt=missing.ckpt"], "missing.ckpt"),
    ("granular_pyg.dem.convert", ["missing.dump", "--dem-dt", "2e-5", "--out", "x.h5"], "missing"),
    ("granular_pyg.pretrained.export", ["missing.ckpt", "hopper"], "missing.ckpt"),
]


@pytest.mark.parametrize(("module", "args", "word"), CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_error_line_with_status_2(tmp_path, module, args, word):
    done = subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)},
    )
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert done.returncode == EXIT_INPUT_ERROR, done.stderr[-2000:]
    assert len(errors) == 1 and word in errors[0], done.stderr[-2000:]
    assert "Traceback" not in done.stderr


def test_the_wrapper_passes_results_and_other_exceptions_through(monkeypatch):
    monkeypatch.delenv("GRANULAR_PYG_DEBUG", raising=False)
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    assert reports_errors(lambda x: x + 1)(1) == 2

    def bug():
        raise KeyError("a bug, not bad input")

    with pytest.raises(KeyError):
        reports_errors(bug)()


def test_debug_mode_raises_instead_of_exiting(monkeypatch, capsys):
    def bad():
        raise InputError("x: bad; fix it")

    monkeypatch.setenv("GRANULAR_PYG_DEBUG", "1")
    with pytest.raises(InputError):
        reports_errors(bad)()
    monkeypatch.setenv("GRANULAR_PYG_DEBUG", "0")
    with pytest.raises(SystemExit) as exit_info:
        reports_errors(bad)()
    assert exit_info.value.code == EXIT_INPUT_ERROR
    assert capsys.readouterr().err == "error: x: bad; fix it\n"
