"""The demo runs (geometry; training + rollout + evaluation, shortened), and atomic writes never
leave partial files."""

from __future__ import annotations

import pytest

from granular_pyg import demo
from granular_pyg.io import atomic_write


def test_geometry_demo_writes_its_figure(tmp_path, capsys):
    paths = demo.main(["--out", str(tmp_path), "--particles", "3000", "--stages", "geometry"])
    assert paths["figure"].read_bytes()[:4] == b"\x89PNG"
    out = capsys.readouterr().out
    assert "wall nodes within 5.0 mm" in out
    assert "x faster" in out


@pytest.mark.slow
def test_demo_trains_rolls_out_and_reports(tmp_path, capsys):
    """The demo's training and evaluation stages, shortened: a checkpoint, TensorBoard logs,
    a rollout file and a report that names the test trajectory."""
    short = [
        "model.latent=16",
        "trainer.max_epochs=1",
        "data.train_samples_per_epoch=4",
        "data.val_samples=2",
        "trainer.enable_progress_bar=false",
    ]
    paths = demo.main(
        ["--out", str(tmp_path), "--stages", "train,evaluate", "--steps", "8", *short]
    )
    assert paths["ckpt"].is_file()
    assert any(paths["tensorboard"].glob("events.out.tfevents.*"))
    report = paths["report"].read_text()
    assert "traj_0003.h5" in report and "emd_mean" in report
    assert len(list((tmp_path / "evaluate" / "rollouts").glob("*.h5"))) == 1
    assert "report:" in capsys.readouterr().out


def test_atomic_write_replaces_the_file_whole(tmp_path):
    target = tmp_path / "sub" / "file.txt"
    with atomic_write(target) as fh:
        fh.write("first")
    assert target.read_text() == "first"


def test_atomic_write_keeps_the_old_file_when_interrupted(tmp_path):
    target = tmp_path / "file.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_write(target) as fh:
        fh.write("half")
        raise RuntimeError("killed")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["file.txt"]  # no temporary left over
