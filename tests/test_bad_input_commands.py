"""Bad input and faults against the real command lines (``python -m granular_pyg.<command>``).

Each case runs one command in a subprocess (cwd = the test's folder, the environment of
``tests/test_cli.py``) on small real files copied or written there first, and checks:

- the exit status: 2 for refused input, 0 where the right behaviour is to succeed;
- for refused input, exactly one standard-error line starting with ``error:``, naming the
  offending thing (an option, a file, a key), and no traceback;
- that no input file changed (SHA-256 before and after), and, where the command must refuse
  before any work, that it did not create its output.

Covered: an output that is the input (same path, hard link, symbolic link) or an existing result
(rollout, evaluate, dem.convert); the ways of saying "no ranges" to generate and a rerun into a
dataset made with other settings; an unwritable output folder; unevenly spaced frames; bad
``steps``; bad train values and truncated checkpoints; Hydra composition errors; removing a
stress case; a missing LIGGGHTS binary. Two in-process checks end the module: ``emd`` refuses a
partly-NaN row and the closest point of float32 triangles with 1e10 m edges is finite.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import torch

from granular_pyg.cli import EXIT_INPUT_ERROR
from granular_pyg.errors import InputError
from granular_pyg.io import read_trajectory, write_trajectory
from granular_pyg.pretrained import resolve_checkpoint
from granular_pyg.samples import sample_files
from tests import hostile
from tests.dem.dump_text import falling, plate, write_dump, write_stl
from tests.test_generate import TINY

#: The tiny real hopper of tests/test_generate.py (seconds of LIGGGHTS), without its ranges.
TINY_GENERATE = [o for o in TINY if not o.startswith("scene.ranges")] + ["n=1"]
DUMP_STEPS = range(0, 2001, 125)  # as tests/dem/test_import_checks.py: 17 frames, dem_dt 2e-5
ROLLOUT = ["ckpt=pretrained:hopper", "trajectory=X.h5", "progress=false"]
EVALUATE = ["ckpt=pretrained:hopper", "paraview=0", "progress=false"]


# -- the input files a case asks for, made in its folder --------------------------------------


def _env(tmp_path: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    return {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)} | (extra or {})


def _sample(tmp: Path) -> list[Path]:
    shutil.copyfile(sample_files("hopper", "test")[0], tmp / "X.h5")
    return [tmp / "X.h5"]


def _hard_link(tmp: Path) -> list[Path]:
    os.link(tmp / "X.h5", tmp / "hard.h5")
    return [tmp / "hard.h5"]


def _symlink(tmp: Path) -> list[Path]:
    (tmp / "sym.h5").symlink_to("X.h5")
    return [tmp / "sym.h5"]


def _gap(tmp: Path) -> list[Path]:
    """The sample with frame 5 dropped: one gap twice the spacing of the others."""
    traj = read_trajectory(sample_files("hopper", "test")[0])
    keep = np.delete(np.arange(traj.num_frames), 5)
    dropped = dataclasses.replace(
        traj,
        positions=traj.positions[keep],
        velocities=traj.velocities[keep],
        times=traj.times[keep],
    )
    write_trajectory(dropped, tmp / "gap.h5")
    return [tmp / "gap.h5"]


def _cut_checkpoint(tmp: Path) -> list[Path]:
    data = resolve_checkpoint("pretrained:hopper").read_bytes()
    (tmp / "cut.ckpt").write_bytes(data[:1000])
    return [tmp / "cut.ckpt"]


def _dump(tmp: Path) -> list[Path]:
    return [write_dump(tmp / "dump.liggghts", falling(DUMP_STEPS))]


def _dump_folder(tmp: Path) -> list[Path]:
    (tmp / "dumps").mkdir()
    return [write_dump(tmp / "dumps" / "dump.liggghts", falling(DUMP_STEPS))]


def _stl(tmp: Path) -> list[Path]:
    return [write_stl(tmp / "floor.stl", plate(z=0.0))]


def _earlier_rollout(tmp: Path) -> list[Path]:
    (tmp / "old.h5").write_bytes(b"an earlier result\n")
    return [tmp / "old.h5"]


def _earlier_report(tmp: Path) -> list[Path]:
    (tmp / "ev").mkdir()
    (tmp / "ev" / "report.md").write_text("# an earlier evaluation\n")
    return [tmp / "ev" / "report.md"]


def _locked_folder(tmp: Path) -> list[Path]:
    if os.geteuid() == 0:
        pytest.skip("running as root, which writes into a chmod 0o500 folder anyway")
    (tmp / "locked").mkdir()
    (tmp / "locked").chmod(0o500)
    return []


def _dataset(tmp: Path) -> list[Path]:
    """A one-trajectory dataset made with no ranges (a real, tiny LIGGGHTS run)."""
    done = subprocess.run(
        [sys.executable, "-m", "granular_pyg.generate", *TINY_GENERATE, "scene.ranges={}",
         "out=dataset"],
        cwd=tmp, capture_output=True, text=True, timeout=300, env=_env(tmp),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    return [tmp / "dataset" / "manifest.json", tmp / "dataset" / "traj_0000.h5"]


def _evil_pickle(tmp: Path) -> list[Path]:
    return [hostile.pickle_payload(tmp / "evil.ckpt", tmp / "pwned")]


def _evil_target(how: str, nested: bool = False) -> Callable[[Path], list[Path]]:
    def make(tmp: Path) -> list[Path]:
        path = hostile.config_target(tmp / "evil_cfg.ckpt", tmp / "pwned", how, nested)
        inner = path.with_name(path.stem + "_inner.ckpt")
        return [path, *([inner] if inner.exists() else [])]

    return make


def _edited(name: str, edit: Callable[[dict], object]) -> Callable[[Path], list[Path]]:
    """The shipped hopper's contents changed by ``edit`` (what it returns is saved when not
    None, else the edited dict)."""

    def make(tmp: Path) -> list[Path]:
        ckpt = hostile.shipped()
        saved = edit(ckpt)
        torch.save(ckpt if saved is None else saved, tmp / name)
        return [tmp / name]

    return make


def _cut_manifest(tmp: Path) -> list[Path]:
    """A dataset folder whose manifest was cut off mid-file."""
    (tmp / "data").mkdir()
    (tmp / "data" / "manifest.json").write_text('{"scene_config": {"name": "hop')
    return [tmp / "data" / "manifest.json"]


def _shipped_hopper(tmp: Path) -> list[Path]:
    return [resolve_checkpoint("pretrained:hopper")]


def _history_3(ckpt: dict) -> None:
    ckpt["config"]["model"]["history"] = 3  # its weights were trained with 5


def _no_data(ckpt: dict) -> None:
    del ckpt["config"]["data"]


#: name -> maker(folder) returning the files it made that must not change.
MAKERS: dict[str, Callable[[Path], list[Path]]] = {
    "X.h5": _sample,
    "hard.h5": _hard_link,
    "sym.h5": _symlink,
    "gap.h5": _gap,
    "cut.ckpt": _cut_checkpoint,
    "dump.liggghts": _dump,
    "dumps/": _dump_folder,
    "floor.stl": _stl,
    "old.h5": _earlier_rollout,
    "ev/report.md": _earlier_report,
    "locked/": _locked_folder,
    "dataset/": _dataset,
    # the same dataset, where only its trajectory must stay (a resumed run rewrites its manifest)
    "dataset/traj_0000.h5": lambda tmp: _dataset(tmp)[1:],
    # hostile checkpoints: each makes tmp/pwned if anything it names runs
    "evil.ckpt": _evil_pickle,
    "evil_cfg.ckpt:open": _evil_target("open"),
    "evil_cfg.ckpt:torch.load": _evil_target("torch.load", nested=True),
    # checkpoints that are no training checkpoint, or whose parts disagree
    "weights.ckpt": _edited("weights.ckpt", lambda c: c["state_dict"]),
    "tensor.ckpt": _edited("tensor.ckpt", lambda c: torch.zeros(3)),
    "history3.ckpt": _edited("history3.ckpt", _history_3),
    "nodata.ckpt": _edited("nodata.ckpt", _no_data),
    "shipped:hopper": _shipped_hopper,
    "data/manifest.json": _cut_manifest,
}


# -- checks of a successful run ---------------------------------------------------------------


def _replaced_rollout(tmp: Path, done: subprocess.CompletedProcess) -> None:
    pred = read_trajectory(tmp / "old.h5")
    assert pred.metadata["steps"] == 1 and pred.metadata["truth_file"] == "X.h5"


def _replaced_report(tmp: Path, done: subprocess.CompletedProcess) -> None:
    report = (tmp / "ev" / "report.md").read_text()
    assert "an earlier evaluation" not in report and "X.h5" in report
    assert (tmp / "ev" / "rollouts" / "files_X.h5").is_file()


def _no_ranges_sampled(tmp: Path, done: subprocess.CompletedProcess) -> None:
    manifest = json.loads((tmp / "data" / "manifest.json").read_text())
    assert not manifest["scene_config"].get("ranges")
    params = manifest["trajectories"][0]["params"]
    build = manifest["scene_config"]["build"]
    assert params == build and params["num_particles"] == 200 and params["alpha_deg"] == 60.0
    assert read_trajectory(tmp / "data" / "traj_0000.h5").num_particles == 200


def _resumed_nothing_to_do(tmp: Path, done: subprocess.CompletedProcess) -> None:
    assert "1 of 1 trajectories present" in done.stdout, done.stdout


def _huge_steps_bounded(tmp: Path, done: subprocess.CompletedProcess) -> None:
    """``steps=1e9``: refused by the memory bound, or (on a machine with petabytes) a rollout
    that stopped early and said so; never a run that goes on."""
    if done.returncode == EXIT_INPUT_ERROR:
        line = _error_lines(done)
        assert len(line) == 1 and "steps:" in line[0] and "GiB" in line[0], done.stderr[-2000:]
        assert not (tmp / "p.h5").exists()
    else:
        assert done.returncode == 0 and "stopped after step" in done.stdout, done.stderr[-2000:]


def _stress_without_drum(tmp: Path, done: subprocess.CompletedProcess) -> None:
    results = json.loads((tmp / "st" / "stress.json").read_text())
    cases = set(results) - {"command"}
    assert cases == {"hopper_resting", "hopper_discharging", "drum_precision"}, cases


def _stress_figure(tmp: Path) -> None:
    assert (tmp / "st" / "stress.png").is_file() and (tmp / "st" / "stress.json").is_file()


# -- the cases ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One command line, what it is given and what it must do.

    ``status`` 2 (refused): one ``error:`` line containing every one of ``words``. ``inputs``
    name :data:`MAKERS` entries whose files are made first and must not change; ``made`` ones
    are made but may change (an output the case allows to be replaced). ``absent``: paths that
    must not exist afterwards. ``check(tmp_path, completed)``: more assertions; when set for a
    status ``None`` case, it judges the status itself."""

    id: str
    module: str
    args: list[str]
    status: int | None = EXIT_INPUT_ERROR
    words: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    made: tuple[str, ...] = ()
    absent: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)
    check: Callable[[Path, subprocess.CompletedProcess], None] | None = None
    timeout: int = 300
    slow: bool = False
    xfail: str | None = None


def _rollout(id, args, args_replace: bool = False, **kw) -> Case:
    """A rollout of ``X.h5``; ``args_replace``: ``args`` name their own ``ckpt=``."""
    base = [a for a in ROLLOUT if not (args_replace and a.startswith("ckpt="))]
    return Case(id, "granular_pyg.rollout", [*base, *args], **({"inputs": ("X.h5",)} | kw))


CASES = [
    # 1. the output is the input: the same path, a hard link, a symbolic link (even when
    #    replacing is allowed)
    _rollout("rollout-out-is-the-input", ["out=X.h5"], words=("out:", "X.h5", "is the input")),
    _rollout("rollout-out-is-the-input-overwrite", ["out=X.h5", "overwrite=true"],
             words=("out:", "is the input X.h5")),
    _rollout("rollout-out-is-a-hard-link-to-the-input", ["out=hard.h5"],
             inputs=("X.h5", "hard.h5"), words=("out:", "hard.h5", "is the input X.h5")),
    _rollout("rollout-out-is-a-symlink-to-the-input", ["out=sym.h5", "overwrite=true"],
             inputs=("X.h5", "sym.h5"), words=("out:", "sym.h5", "is the input X.h5")),
    # 2. an existing output: refused without overwrite=true, replaced with it
    _rollout("rollout-out-exists", ["out=old.h5"], inputs=("X.h5", "old.h5"),
             words=("out:", "old.h5", "overwrite=true")),
    _rollout("rollout-out-exists-overwrite", ["out=old.h5", "overwrite=true", "steps=1"],
             made=("old.h5",), status=0, check=_replaced_rollout),
    Case("evaluate-report-exists", "granular_pyg.evaluate",
         [*EVALUATE, "trajectories=[X.h5]", "steps=1", "out=ev"], inputs=("X.h5", "ev/report.md"),
         words=("out:", "report.md", "overwrite=true"), absent=("ev/rollouts",)),
    Case("evaluate-report-exists-overwrite", "granular_pyg.evaluate",
         [*EVALUATE, "trajectories=[X.h5]", "steps=1", "out=ev", "overwrite=true"],
         inputs=("X.h5",), made=("ev/report.md",), status=0, check=_replaced_report),
    # 3. dem.convert writing over one of its inputs (a dump, an STL wall, inside a dump folder)
    Case("convert-out-is-the-dump", "granular_pyg.dem_import.convert",
         ["dump.liggghts", "--stl", "floor.stl", "--dem-dt", "2e-5", "--out", "dump.liggghts"],
         inputs=("dump.liggghts", "floor.stl"), words=("--out", "dump.liggghts", "is the input")),
    Case("convert-out-is-the-dump-overwrite", "granular_pyg.dem_import.convert",
         ["dump.liggghts", "--dem-dt", "2e-5", "--out", "dump.liggghts", "--overwrite"],
         inputs=("dump.liggghts",), words=("--out", "dump.liggghts", "is the input")),
    Case("convert-out-is-the-stl", "granular_pyg.dem_import.convert",
         ["dump.liggghts", "--stl", "floor.stl", "--dem-dt", "2e-5", "--out", "floor.stl",
          "--overwrite"],
         inputs=("dump.liggghts", "floor.stl"), words=("--out", "floor.stl", "is the input")),
    Case("convert-out-inside-the-dump-folder", "granular_pyg.dem_import.convert",
         ["dumps", "--dem-dt", "2e-5", "--out", "dumps/traj.h5"],
         inputs=("dumps/",), words=("--out", "is the input dumps"), absent=("dumps/traj.h5",)),
    # 4. generate: three ways of saying "no ranges"; a rerun with other settings
    *[
        Case(f"generate-no-ranges-{name}", "granular_pyg.generate",
             [*TINY_GENERATE, override, "out=data"], status=0, check=_no_ranges_sampled)
        for name, override in [
            ("empty-dict", "scene.ranges={}"),
            ("deleted", "~scene.ranges"),
            ("null", "scene.ranges=null"),
        ]
    ],
    Case("generate-rerun-other-scene-setting", "granular_pyg.generate",
         [*TINY_GENERATE, "scene.ranges={}", "scene.build.alpha_deg=70.0", "out=dataset"],
         inputs=("dataset/",), words=("out:", "scene_config.build.alpha_deg", "60.0 -> 70.0"),
         absent=("dataset/traj_0001.h5",)),
    Case("generate-rerun-other-n", "granular_pyg.generate",
         [*TINY_GENERATE[:-1], "n=2", "scene.ranges={}", "out=dataset"],
         inputs=("dataset/",), words=("out:", "n: 1 -> 2"), absent=("dataset/traj_0001.h5",)),
    Case("generate-rerun-other-seed", "granular_pyg.generate",
         [*TINY_GENERATE, "scene.ranges={}", "seed=3", "out=dataset"],
         inputs=("dataset/",), words=("out:", "seed: 0 -> 3")),
    # the same settings, "no ranges" said another way: the same dataset, nothing to do
    Case("generate-rerun-same-settings-no-ranges-said-otherwise", "granular_pyg.generate",
         [*TINY_GENERATE, "~scene.ranges", "out=dataset"], inputs=("dataset/traj_0000.h5",),
         status=0,
         check=_resumed_nothing_to_do),
    # 5. an output folder that cannot be written: refused before the rollout is computed
    _rollout("rollout-out-folder-unwritable", ["out=locked/p.h5"], inputs=("X.h5", "locked/"),
             words=("out:", "locked", "not writable"), absent=("locked/p.h5",)),
    Case("evaluate-out-folder-unwritable", "granular_pyg.evaluate",
         [*EVALUATE, "trajectories=[X.h5]", "steps=1", "out=locked"], inputs=("X.h5", "locked/"),
         words=("out:", "locked", "not writable"), absent=("locked/report.md",)),
    # 6. a dropped frame: uneven spacing
    Case("rollout-uneven-frame-spacing", "granular_pyg.rollout",
         ["ckpt=pretrained:hopper", "trajectory=gap.h5", "out=p.h5", "progress=false"],
         inputs=("gap.h5",), words=("times:", "not evenly spaced"), absent=("p.h5",)),
    Case("evaluate-uneven-frame-spacing", "granular_pyg.evaluate",
         [*EVALUATE, "trajectories=[gap.h5]", "out=ev"], inputs=("gap.h5",),
         words=("times:", "not evenly spaced"), absent=("ev/report.md", "ev/rollouts")),
    # 7. bad steps; a huge one stays bounded
    *[
        _rollout(f"rollout-steps={value}", [f"steps={value}", "out=p.h5"],
                 words=("steps:", shown), absent=("p.h5",))
        for value, shown in [("2.7", "2.7"), ("abc", "'abc'"), ("-1", "-1")]
    ],
    _rollout("rollout-steps=1e9", ["steps=1e9", "out=p.h5"], status=None, timeout=120,
             check=_huge_steps_bounded),
    # 8. bad train values; a truncated checkpoint to resume from or to roll out
    Case("train-batch-size-0", "granular_pyg.train", ["data.batch_size=0"],
         words=("data.batch_size", "got 0")),
    Case("train-batch-size-abc", "granular_pyg.train", ["data.batch_size=abc"],
         words=("data.batch_size", "'abc'")),
    Case("train-lr-abc", "granular_pyg.train", ["optim.lr=abc"], words=("optim.lr", "'abc'")),
    Case("train-truncated-ckpt-path", "granular_pyg.train", ["ckpt_path=cut.ckpt"],
         inputs=("cut.ckpt",), words=("ckpt_path", "cut.ckpt", "not a readable checkpoint")),
    Case("rollout-truncated-ckpt", "granular_pyg.rollout",
         ["ckpt=cut.ckpt", "trajectory=X.h5", "out=p.h5", "progress=false"],
         inputs=("X.h5", "cut.ckpt"), words=("cut.ckpt", "not a readable checkpoint"),
         absent=("p.h5",)),
    # 9. command lines Hydra cannot compose; removing a stress case; LIGGGHTS missing
    Case("train-unknown-key", "granular_pyg.train", ["model.nope=3"], words=("model.nope",)),
    Case("train-model-dt", "granular_pyg.train", ["model.dt=0.01"],
         words=("model.dt", "not a setting", "data.frames_per_step")),
    Case("train-model-dt-multirun", "granular_pyg.train", ["--multirun", "+model.dt=0.01,0.02"],
         words=("model.dt", "not a setting", "data.frames_per_step")),
    Case("train-unknown-option", "granular_pyg.train", ["model=v9"],
         words=("model/v9", "v1, v2, v3")),
    Case("train-malformed-override", "granular_pyg.train", ["trainer.max_epochs=[1"],
         words=("'[1'",)),
    Case("rollout-unknown-key", "granular_pyg.rollout", ["ckpt=pretrained:hopper", "stepz=3"],
         words=("stepz",)),
    Case("stress-without-drum", "granular_pyg.stress",
         ["~cases.drum", "quick=true", "quick_steps=2", "progress=false", "hydra.run.dir=st"],
         status=0, check=_stress_without_drum, slow=True),
    Case("generate-liggghts-missing", "granular_pyg.generate", [*TINY_GENERATE, "out=data"],
         env={"GRANULAR_PYG_LIGGGHTS": "/nonexistent/liggghts"},
         words=("/nonexistent/liggghts", "liggghts=<path>", "GRANULAR_PYG_LIGGGHTS"),
         absent=("data/traj_0000.h5",)),
    # 10. hostile checkpoints (issue 36): refused unread or unbuilt, no marker file, by every
    #     command that reads one
    _rollout("rollout-pickle-payload", ["ckpt=evil.ckpt", "out=p.h5"], args_replace=True,
             inputs=("X.h5", "evil.ckpt"), words=("ckpt:", "evil.ckpt", "exec",
             "refused unread"), absent=("pwned", "p.h5")),
    _rollout("rollout-config-target-open", ["ckpt=evil_cfg.ckpt", "out=p.h5"], args_replace=True,
             inputs=("X.h5", "evil_cfg.ckpt:open"), words=("model._target_='builtins.open'",
             "not one of the package's model classes"), absent=("pwned", "p.h5")),
    Case("evaluate-pickle-payload", "granular_pyg.evaluate",
         ["ckpt=evil.ckpt", "paraview=0", "progress=false", "trajectories=[X.h5]", "out=ev"],
         inputs=("X.h5", "evil.ckpt"), words=("evil.ckpt", "refused unread"),
         absent=("pwned", "ev/report.md")),
    Case("evaluate-config-target-torch-load", "granular_pyg.evaluate",
         ["ckpt=evil_cfg.ckpt", "paraview=0", "progress=false", "trajectories=[X.h5]", "out=ev"],
         inputs=("X.h5", "evil_cfg.ckpt:torch.load"),
         words=("model.processor._target_='torch.load'", "not one of the package's model"),
         absent=("pwned", "ev/report.md")),
    Case("train-resume-pickle-payload", "granular_pyg.train", ["ckpt_path=evil.ckpt"],
         inputs=("evil.ckpt",), words=("ckpt_path:", "evil.ckpt", "refused unread"),
         absent=("pwned",)),
    Case("train-finetune-pickle-payload", "granular_pyg.train",
         ["+experiment=finetune", "init=evil.ckpt", "data.root=null", "data.sample=hopper"],
         inputs=("evil.ckpt",), words=("init:", "evil.ckpt", "refused unread"),
         absent=("pwned",)),
    Case("train-finetune-config-target-torch-load", "granular_pyg.train",
         ["+experiment=finetune", "init=evil_cfg.ckpt", "data.root=null", "data.sample=hopper"],
         inputs=("evil_cfg.ckpt:torch.load",), words=("init:", "model.processor._target_"),
         absent=("pwned",)),
    Case("export-pickle-payload", "granular_pyg.pretrained.export",
         ["evil.ckpt", "hopper", "--out", "o.ckpt"], inputs=("evil.ckpt", "shipped:hopper"),
         words=("evil.ckpt", "refused unread"), absent=("pwned", "o.ckpt")),
    Case("stress-pickle-payload", "granular_pyg.stress",
         ["cases.hopper_discharging.ckpt=evil.ckpt", "~cases.hopper_resting", "~cases.drum",
          "~cases.drum_precision", "quick=true", "quick_steps=2", "progress=false",
          "hydra.run.dir=st"],
         inputs=("evil.ckpt",), words=("evil.ckpt", "refused unread"), absent=("pwned",)),
    Case("bench-rollout-speed-pickle-payload", "granular_pyg.bench",
         ["suite=rollout_speed", "suite.run.ckpts=[evil.ckpt]", "hydra.run.dir=b"],
         inputs=("evil.ckpt",), words=("evil.ckpt", "refused unread"), absent=("pwned",)),
    Case("one-step-bias-pickle-payload", "granular_pyg.experiments.one_step_bias",
         ["ckpt=evil.ckpt", "files=[X.h5]", "out=ob"], inputs=("X.h5", "evil.ckpt"),
         words=("evil.ckpt", "refused unread"), absent=("pwned",)),
    # 11. strict booleans; nothing replaced without being asked
    _rollout("rollout-overwrite-no", ["out=old.h5", "overwrite=no", "steps=1"],
             inputs=("X.h5", "old.h5"), words=("overwrite:", "'no'", "true or false")),
    _rollout("rollout-wall-guard-flase", ["wall_guard=flase", "out=p.h5", "steps=1"],
             words=("wall_guard:", "'flase'", "true or false"), absent=("p.h5",)),
    Case("train-compile-yes", "granular_pyg.train", ["compile=yes"],
         words=("compile:", "'yes'", "true or false")),
    Case("export-into-the-package-unasked", "granular_pyg.pretrained.export",
         ["pretrained:hopper", "hopper"], inputs=("shipped:hopper",),
         words=("--out", "--overwrite", "pretrained:hopper")),
    Case("export-out-exists", "granular_pyg.pretrained.export",
         ["pretrained:hopper", "hopper", "--out", "old.h5"], inputs=("shipped:hopper", "old.h5"),
         words=("--out", "old.h5", "--overwrite")),
    # 12. checkpoints that are not what they say
    _rollout("rollout-ckpt-state-dict", ["ckpt=weights.ckpt", "out=p.h5"], args_replace=True,
             inputs=("X.h5", "weights.ckpt"), words=("ckpt:", "bare state_dict"),
             absent=("p.h5",)),
    _rollout("rollout-ckpt-config-and-weights-disagree", ["ckpt=history3.ckpt", "out=p.h5"],
             args_replace=True, inputs=("X.h5", "history3.ckpt"),
             words=("history3.ckpt", "weights do not fit", "of another shape"), absent=("p.h5",)),
    Case("rollout-ckpt-without-data-section", "granular_pyg.rollout",
         ["ckpt=nodata.ckpt", "out=p.h5", "progress=false"], inputs=("nodata.ckpt",),
         words=("trajectory:", "no training data", "trajectory=<file.h5>"), absent=("p.h5",)),
    Case("evaluate-ckpt-without-data-section", "granular_pyg.evaluate",
         ["ckpt=nodata.ckpt", "paraview=0", "progress=false", "out=ev"], inputs=("nodata.ckpt",),
         words=("root:", "no training data", "trajectories="), absent=("ev/report.md",)),
    Case("train-ckpt-path-state-dict", "granular_pyg.train", ["ckpt_path=weights.ckpt"],
         inputs=("weights.ckpt",), words=("ckpt_path:", "bare state_dict", "init=")),
    Case("train-ckpt-path-pretrained", "granular_pyg.train", ["ckpt_path=pretrained:hopper"],
         words=("ckpt_path:", "slim", "init=")),
    Case("export-unknown-sample", "granular_pyg.pretrained.export",
         ["pretrained:hopper", "hopper", "--out", "o.ckpt", "--sample", "nope"],
         words=("--sample", "'nope'", "hopper"), absent=("o.ckpt",)),
    Case("export-bare-tensor", "granular_pyg.pretrained.export",
         ["tensor.ckpt", "hopper", "--out", "o.ckpt"], inputs=("tensor.ckpt",),
         words=("tensor.ckpt", "holds a Tensor"), absent=("o.ckpt",)),
    # 13. meaningless or raw: one line each
    _rollout("rollout-threads-0", ["threads=0", "out=p.h5"], words=("threads:", "got 0"),
             absent=("p.h5",)),
    _rollout("rollout-threads--1", ["threads=-1", "out=p.h5"], words=("threads:", "got -1"),
             absent=("p.h5",)),
    _rollout("rollout-ckpt-empty", ["ckpt=", "out=p.h5"], args_replace=True,
             words=("ckpt: empty", "pretrained:hopper"), absent=("p.h5",)),
    _rollout("rollout-skin-abc", ["skin=abc", "out=p.h5"], words=("skin:", "'abc'"),
             absent=("p.h5",)),
    Case("rollout-trajectory-is-a-folder", "granular_pyg.rollout",
         ["ckpt=pretrained:hopper", "trajectory=dumps", "out=p.h5"], inputs=("dumps/",),
         words=("trajectory:", "dumps", "is a folder"), absent=("p.h5",)),
    Case("rollout-non-ascii-path", "granular_pyg.rollout",
         ["ckpt=pretrained:hopper", "trajectory=données/X.h5"],
         words=("trajectory:", "quote")),
    Case("train-max-epochs--5", "granular_pyg.train", ["trainer.max_epochs=-5"],
         words=("trainer", "max_epochs")),
    Case("train-noise-std-negative", "granular_pyg.train", ["data.noise_std=-1e-4"],
         words=("data.noise_std:", ">= 0", "-0.0001")),
    Case("train-noise-std-nan", "granular_pyg.train", ["data.noise_std=nan"],
         words=("data.noise_std:", "nan")),
    Case("train-finetune-model-latent-32", "granular_pyg.train",
         ["+experiment=finetune", "init=pretrained:hopper", "data.root=null",
          "data.sample=hopper", "model.latent=32"],
         words=("model.latent=32", "fine-tuning keeps the architecture", "latent")),
    Case("stress-quick-steps-1", "granular_pyg.stress",
         ["~cases.hopper_discharging", "~cases.drum", "~cases.drum_precision", "quick=true",
          "quick_steps=1", "progress=false", "hydra.run.dir=st"],
         status=0, check=lambda tmp, done: _stress_figure(tmp)),
    Case("generate-dem-dt-0", "granular_pyg.generate",
         [*TINY_GENERATE, "scene.ranges={}", "scene.build.dem_dt=0", "out=data"],
         words=("dem_dt", "> 0", "got 0"), absent=("data/traj_0000.h5",)),
    Case("generate-num-particles-0", "granular_pyg.generate",
         [*(o for o in TINY_GENERATE if "num_particles" not in o), "scene.ranges={}",
          "scene.build.num_particles=0", "out=data"],
         words=("num_particles",), absent=("data/traj_0000.h5",)),
    Case("generate-manifest-cut-off", "granular_pyg.generate", [*TINY_GENERATE, "out=data"],
         inputs=("data/manifest.json",), words=("manifest.json", "not valid JSON", "rerun"),
         absent=("data/traj_0000.h5",)),
    Case("train-run-folder-unwritable", "granular_pyg.train", ["hydra.run.dir=locked/run"],
         inputs=("locked/",), words=("hydra.run.dir", "locked", "not writable")),
]  # fmt: skip


def _param(case: Case):
    marks = [pytest.mark.slow] if case.slow else []
    if case.xfail:
        marks.append(pytest.mark.xfail(strict=True, reason=case.xfail))
    return pytest.param(case, id=case.id, marks=marks)


def _error_lines(done: subprocess.CompletedProcess) -> list[str]:
    return [line for line in done.stderr.splitlines() if line.startswith("error:")]


def _digests(files: list[Path]) -> dict[Path, str]:
    return {f: hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_a_command_refuses_bad_input_and_leaves_its_inputs(tmp_path, case):
    inputs = [f for name in case.inputs for f in MAKERS[name](tmp_path)]
    for name in case.made:
        MAKERS[name](tmp_path)
    before = _digests(inputs)
    done = subprocess.run(
        [sys.executable, "-m", case.module, *case.args],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=case.timeout,
        env=_env(tmp_path, case.env),
    )
    if (tmp_path / "locked").exists():
        (tmp_path / "locked").chmod(0o700)  # for the clean-up
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    if case.status is not None:
        assert done.returncode == case.status, done.stderr[-3000:]
    if case.status == EXIT_INPUT_ERROR:
        errors = _error_lines(done)
        assert len(errors) == 1, done.stderr[-3000:]
        missing = [w for w in case.words if w not in errors[0]]
        assert not missing, f"{missing} not in {errors[0]!r}"
    assert _digests(inputs) == before, "an input file changed"
    if "sym.h5" in case.inputs:
        assert os.readlink(tmp_path / "sym.h5") == "X.h5"
    if "hard.h5" in case.inputs:
        assert (tmp_path / "hard.h5").stat().st_ino == (tmp_path / "X.h5").stat().st_ino
    for path in case.absent:
        assert not (tmp_path / path).exists(), f"{path} was created"
    if case.check is not None:
        case.check(tmp_path, done)


# -- 10. metrics, in process ------------------------------------------------------------------


@pytest.mark.parametrize("side", ["a", "b"])
def test_emd_refuses_a_row_that_is_nan_in_only_some_coordinates(side):
    from granular_pyg.metrics import emd

    good = np.random.default_rng(0).uniform(0.0, 0.1, (5, 3))
    bad = good.copy()
    bad[2, 1] = np.nan
    args = (bad, good) if side == "a" else (good, bad)
    with pytest.raises(InputError, match=rf"emd: {side} has 1 row\(s\).*row 2"):
        emd(*args)
    gone = good.copy()
    gone[2] = np.nan  # a particle that left: NaN in every coordinate, dropped
    assert np.isfinite(emd(gone, good, sink=np.zeros(3)))


def test_closest_point_of_float32_triangles_with_1e10_m_edges_is_finite():
    from granular_pyg.geometry import closest_point_on_triangles

    tri = torch.tensor([[[0.0, 0.0, 0.0], [1e10, 0.0, 0.0], [0.0, 1e10, 0.0]]] * 3)
    points = torch.tensor([[1e9, 1e9, 5.0], [-1e9, -1e9, 0.0], [2e10, 2e10, -3.0]])
    closest, sq_dist = closest_point_on_triangles(points, tri)
    assert closest.dtype == torch.float32 and sq_dist.dtype == torch.float32
    assert torch.isfinite(closest).all() and torch.isfinite(sq_dist).all()
    expected = torch.tensor([[1e9, 1e9, 0.0], [0.0, 0.0, 0.0], [5e9, 5e9, 0.0]])
    assert torch.allclose(closest, expected, rtol=1e-5, atol=1.0)
