"""The geometry demo runs, and atomic writes never leave partial files."""

from __future__ import annotations

import pytest

from granular_pyg import demo
from granular_pyg.io import atomic_write


def test_demo_writes_its_figure(tmp_path, capsys):
    figure = demo.main(["--out", str(tmp_path), "--particles", "3000"])
    assert figure.read_bytes()[:4] == b"\x89PNG"
    out = capsys.readouterr().out
    assert "wall nodes within 5.0 mm" in out
    assert "x faster" in out


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
