"""Sweeps on a cluster through Hydra's submitit launcher: ``hydra/launcher=slurm`` composes to
submitit's SLURM launcher with the project's defaults, and the same sweeps of ``generate`` and
``train`` run to completion under ``hydra/launcher=submitit_local`` (one process per point)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_dir

from granular_pyg.config import CONF_DIR
from tests.test_generate import TINY


@pytest.mark.parametrize("command", ["generate", "train"])
def test_the_slurm_preset_composes_to_submitit_with_its_defaults(command):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose(
            command,
            ["hydra/launcher=slurm", "hydra.launcher.partition=cpu"],
            return_hydra_config=True,
        )
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("submitit_launcher.SlurmLauncher")
    assert (launcher.partition, launcher.cpus_per_task, launcher.timeout_min) == ("cpu", 2, 720)


def _sweep(tmp_path, module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            module,
            "-m",
            "hydra/launcher=submitit_local",
            "hydra.launcher.timeout_min=10",
            "hydra.sweep.dir=sweep",
            *args,
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.slow
def test_a_local_submitit_sweep_of_train_runs_every_point(tmp_path):
    done = _sweep(
        tmp_path,
        "granular_pyg.train",
        "model.latent=16,32",
        "trainer.fast_dev_run=true",
        "threads=1",
        "trainer.enable_progress_bar=false",
        "hydra.sweep.subdir=${model.latent}",
    )
    assert done.returncode == 0, done.stderr[-3000:]
    for latent in (16, 32):
        assert (tmp_path / "sweep" / str(latent) / "checkpoints" / "last.ckpt").is_file()


@pytest.mark.slow
def test_a_local_submitit_sweep_of_generate_makes_one_dataset_per_point(tmp_path):
    done = _sweep(
        tmp_path,
        "granular_pyg.generate",
        *TINY,
        "n=1",
        "jobs=1",
        "seed=1,2",
        "out=data/seed${seed}",
    )
    assert done.returncode == 0, done.stderr[-3000:]
    for seed in (1, 2):
        manifest = json.loads((tmp_path / f"data/seed{seed}/manifest.json").read_text())
        assert sum(len(v) for v in manifest["splits"].values()) == 1
