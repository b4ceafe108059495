"""The README's quickstart runs as written, on real LIGGGHTS runs made here."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from granular_pyg.config import compose
from granular_pyg.generate import generate

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _block(heading: str) -> str:
    """The first ```bash block after ``heading``."""
    after = README[README.index(heading) :]
    return re.search(r"```bash\n(.*?)```", after, re.S).group(1)


def test_the_readme_is_short_and_cites_only_files_in_the_repository():
    assert len(README) <= 12_000
    for path in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README):
        if not path.startswith("http"):
            assert (ROOT / path).exists(), path
    for doc in (ROOT / "docs").glob("*.md"):
        for path in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", doc.read_text()):
            if not path.startswith("http"):
                assert (doc.parent / path).exists(), f"{doc.name}: {path}"


@pytest.mark.slow
def test_the_quickstart_runs_as_written(tmp_path):
    """Four real LIGGGHTS hopper runs (200 particles, 0.1 s) laid out as a user's folders
    ``run0..run3/{dumps/, *.stl, in.liggghts}``; then each quickstart line, with ``<time>``
    replaced by the training run's folder."""
    made = tmp_path / "made"
    cfg = compose(
        "generate",
        [
            "scene=hopper",
            "scene.build.num_particles=200",
            "scene.build.duration=0.1",
            "scene.build.t_open=0.01",
            "scene.build.settle_time=0.15",
            "scene.ranges.num_particles=[180,200]",
            "n=4",
            "keep_workdirs=true",
            "progress=false",
            f"out={made}",
        ],
    )
    generate(cfg)
    for i in range(4):
        work, run = made / ".work" / f"traj_{i:04d}", tmp_path / f"run{i}"
        (run / "dumps").mkdir(parents=True)
        shutil.copy(work / "traj.dump", run / "dumps")
        shutil.copy(work / "in.liggghts", run)
        for stl in work.glob("*.stl"):
            shutil.copy(stl, run)
    env = os.environ | {"PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    script = _block("## Quickstart")
    cut = script.rindex("\n", 0, script.index("<time>"))  # the lines that need the run
    before, after = script[:cut], script[cut:]
    for part in (before, after):
        if "<time>" in part:
            (run_dir,) = (tmp_path / "outputs" / "train").iterdir()
            part = part.replace("outputs/train/<time>", str(run_dir.relative_to(tmp_path)))
        done = subprocess.run(
            ["bash", "-euo", "pipefail", "-c", part],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
        )
        assert done.returncode == 0, f"{part}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    assert len(list((tmp_path / "data" / "mine").glob("run*.h5"))) == 4
    assert list(tmp_path.glob("outputs/rollout/*/rollout.h5"))
    assert list(tmp_path.glob("outputs/evaluate/*/report.md"))
