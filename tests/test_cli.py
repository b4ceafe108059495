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
    ("granular_pyg.experiments.one_step_bias", ["ckpt=missing.ckpt", "files=[a.h5]"], "missing"),
    ("granular_pyg.experiments.one_step_bias", ["ckpt=missing.ckpt"], "files=..."),
    (
        "granular_pyg.dem_import.convert",
        ["missing.dump", "--dem-dt", "2e-5", "--out", "x.h5"],
        "missing",
    ),
    ("granular_pyg.pretrained.export", ["missing.ckpt", "hopper"], "missing.ckpt"),
    ("granular_pyg.train", ["data.batch_size=0"], "data.batch_size"),
    ("granular_pyg.evaluate", ["ckpt=pretrained:hopper", "out=.", "steps=2.5"], "steps"),
    ("granular_pyg.generate", ["n=3", "out=x", "splits={train:0.0,valid:0.5,test:0.5}"], "splits"),
    ("granular_pyg.data.combine", ["empty_folder"], "empty_folder"),
    ("granular_pyg.train", ["optim.lr=abc"], "optim.lr"),
    # command lines Hydra cannot compose: refused before any work, in the same style
    ("granular_pyg.train", ["model.nope=3"], "+model.nope=3"),
    ("granular_pyg.train", ["model=v9"], "v1, v2, v3"),
    ("granular_pyg.train", ["trainer.max_epochs=[1"], "[1"),
    ("granular_pyg.train", ["data.root=${nope}"], "data.root"),
    ("granular_pyg.rollout", ["stepz=3"], "+stepz=3"),
    ("granular_pyg.evaluate", ["~nope"], "nope"),
    ("granular_pyg.generate", ["scene=hopperx", "out=x"], "hopperx"),
    ("granular_pyg.compare", ["runz=[a]"], "runz"),
    ("granular_pyg.stress", ["~cases.nope"], "cases.nope"),
    ("granular_pyg.bench", ["suite=nope"], "nope"),
    ("granular_pyg.experiments.one_step_bias", ["ckpz=a"], "ckpz"),
    ("granular_pyg.experiments.reflection", ["ckpz=a"], "ckpz"),
]


@pytest.mark.parametrize(
    ("module", "args", "word"), CASES, ids=[f"{c[0]}:{' '.join(c[1])}" for c in CASES]
)
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


def test_a_truncated_checkpoint_to_resume_is_one_error_line(tmp_path):
    from granular_pyg.pretrained import resolve_checkpoint

    data = resolve_checkpoint("pretrained:hopper").read_bytes()
    (tmp_path / "cut.ckpt").write_bytes(data[: len(data) // 2])
    done = subprocess.run(
        [sys.executable, "-m", "granular_pyg.train", "ckpt_path=cut.ckpt"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == EXIT_INPUT_ERROR and "Traceback" not in done.stderr
    assert "cut.ckpt is not a readable checkpoint" in done.stderr


def test_removing_a_stress_case_leaves_the_others_resolvable():
    from omegaconf import OmegaConf

    from granular_pyg.config import compose

    for case in ("drum", "hopper_resting", "drum_precision"):
        cfg = compose("stress", [f"~cases.{case}"])
        resolved = OmegaConf.to_container(cfg.cases, resolve=True)
        assert case not in resolved and all(
            c["ckpt"].startswith("pretrained:") for c in resolved.values()
        )


def test_a_composition_error_becomes_one_line_with_the_options_inline():
    from granular_pyg.cli import composition_message

    text = (
        "In 'train': Could not find 'model/v9'\n\nAvailable options in 'model':\n\tbase\n\tv1\n"
        "Config search path:\n\tprovider=hydra, path=pkg://hydra.conf\n"
    )
    assert composition_message(Exception(text)) == (
        "In 'train': Could not find 'model/v9'; Available options in 'model': base, v1"
    )
