"""A scene file outside the checkout: ``generate scene=/path/my.yaml`` (and Hydra's own
``--config-dir /path`` with ``/path/scene/my.yaml``), from any working directory."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from granular_pyg.errors import InputError
from granular_pyg.generate import scene_file_arguments

REPO = Path(__file__).resolve().parents[1]


def _my_hopper(folder: Path) -> Path:
    text = (REPO / "conf" / "scene" / "hopper.yaml").read_text()
    text = text.replace("name: hopper", "name: my_hopper").replace(
        "alpha_deg: 60.0 ", "alpha_deg: 55.0 "
    )
    path = folder / "scene" / "my_hopper.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(text)
    return path


def _generate_cfg(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = os.environ | {"PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [sys.executable, "-m", "granular_pyg.generate", *args, "--cfg", "job"],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize("how", ["path", "config-dir"])
def test_a_scene_file_outside_the_checkout_is_used(tmp_path, how):
    path = _my_hopper(tmp_path / "mine")
    args = (
        [f"scene={path}"]
        if how == "path"
        else ["--config-dir", str(tmp_path / "mine"), "scene=my_hopper"]
    )
    done = _generate_cfg(tmp_path, *args, "n=1")
    assert done.returncode == 0, done.stderr
    assert "name: my_hopper" in done.stdout and "alpha_deg: 55.0" in done.stdout


def test_a_missing_scene_file_is_one_error_line(tmp_path):
    done = _generate_cfg(tmp_path, f"scene={tmp_path / 'nope.yaml'}")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"error: scene: {tmp_path / 'nope.yaml'} is not a file; give an existing scene YAML "
        "(a copy of conf/scene/mesh.yaml) or the name of a shipped scene (scene=hopper)"
    ]


def test_shipped_scene_names_pass_unchanged_and_a_shadowing_file_is_renamed(tmp_path):
    assert scene_file_arguments(["scene=hopper", "n=2"]) == ["scene=hopper", "n=2"]
    shadow = tmp_path / "hopper.yaml"
    shadow.write_text("name: mine\n")
    args = scene_file_arguments([f"scene={shadow}"])
    assert args[0].startswith("--config-dir=") and args[1] == "scene=hopper_file"
    assert (Path(args[0].split("=", 1)[1]) / "scene" / "hopper_file.yaml").read_text() == (
        "name: mine\n"
    )
    with pytest.raises(InputError, match="not a file"):
        scene_file_arguments(["scene=./missing.yaml"])
