"""The wheel: every package and every config ships, and a non-editable install runs commands."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).resolve().parents[1]


def test_pyproject_lists_every_package_and_maps_conf():
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "granular_pyg").rglob("__init__.py")
    }
    assert set(tool["packages"]) == found | {"granular_pyg.conf"}
    assert tool["package-dir"] == {"granular_pyg.conf": "conf"}
    patterns = tool["package-data"]["granular_pyg.conf"]
    configs = {p.relative_to(ROOT / "conf") for p in (ROOT / "conf").rglob("*.yaml")}
    shipped = {p for pattern in patterns for p in (ROOT / "conf").glob(pattern)}
    assert {p.relative_to(ROOT / "conf") for p in shipped} == configs


def _run(cmd: list[str], cwd: Path, timeout: int = 600) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, (
        f"{' '.join(map(str, cmd))}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    )
    return done


@pytest.mark.slow
def test_a_wheel_installed_elsewhere_runs_train_and_rollout(tmp_path):
    """``pip install .`` (not ``-e``): the configs come from the wheel, commands run from an
    empty folder outside the checkout. The new environment reuses this one's torch and
    torch-cluster through a .pth file (their site-packages, without its editable install)."""
    wheels = tmp_path / "wheels"
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(ROOT),
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(wheels),
            "-q",
        ],
        cwd=tmp_path,
    )
    (wheel,) = wheels.glob("granular_pyg-*.whl")
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], cwd=tmp_path)
    python = venv / "bin" / "python"
    _run([str(python), "-m", "pip", "install", "--no-deps", "-q", str(wheel)], cwd=tmp_path)
    purelib = Path(
        _run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            cwd=tmp_path,
        ).stdout.strip()
    )
    (purelib / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = _run([str(python), "-c", "import granular_pyg.config as c; print(c.CONF_DIR)"], work)
    assert Path(where.stdout.strip()).is_relative_to(purelib)
    _run([str(python), "-m", "granular_pyg.train", "trainer.fast_dev_run=true"], cwd=work)
    out = _run(
        [str(python), "-m", "granular_pyg.rollout", "ckpt=pretrained:hopper", "steps=3"], cwd=work
    )
    assert "3 learned steps" in out.stdout
    assert list(work.glob("outputs/rollout/*/rollout.h5"))
