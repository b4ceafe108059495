"""Meaningless imports refused or counted (issue 36): an STL whose every triangle has zero area,
a binary STL whose header counts more triangles than it holds, atoms that vanish from the dumps
without an outflow (counted in the metadata, one warning), and negative values in e-notation on
the command line (``--dem-dt -2e-5``) read as values."""

from __future__ import annotations

import hashlib
import struct

import numpy as np
import pytest
import trimesh

from granular_pyg.dem_import.convert import main as convert_main
from granular_pyg.dem_import.convert import trajectory_from_dumps
from granular_pyg.errors import InputError
from granular_pyg.scenes.mesh_scene import read_stl
from tests.dem.dump_text import falling, plate, write_dump, write_stl

STEPS = range(0, 2001, 125)


def test_an_stl_whose_every_triangle_has_zero_area_is_refused(tmp_path):
    v = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.0, 0.0]])
    flat = trimesh.Trimesh(v, [[0, 1, 2], [0, 3, 1]], process=False)  # collinear, repeated
    path = write_stl(tmp_path / "line.stl", flat)
    with pytest.raises(InputError, match=r"line\.stl: all 2 triangles of the STL file have zero"):
        read_stl(path)
    read_stl(write_stl(tmp_path / "plate.stl", plate()))  # a real plate reads


def test_a_binary_stl_whose_header_overstates_its_count_names_both_counts(tmp_path):
    tri = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    path = tmp_path / "cut.stl"
    path.write_bytes(b"binary".ljust(80, b" ") + struct.pack("<I", 10) + tri * 3)
    with pytest.raises(InputError, match=r"header counts 10 triangles but the file holds 3"):
        read_stl(path)


def test_atoms_that_vanish_without_an_outflow_are_counted_and_warned_about(tmp_path, capsys):
    frames = falling(STEPS)
    frames = [(s, i[:-2], p[:-2], v[:-2]) if k >= 10 else (s, i, p, v)
              for k, (s, i, p, v) in enumerate(frames)]  # fmt: skip
    dump = write_dump(tmp_path / "dump.liggghts", frames)
    traj = trajectory_from_dumps([dump], [], 2e-5)
    assert traj.metadata["vanished"] == 2 and traj.metadata["left_through_outflow"] == 0
    err = capsys.readouterr().err
    assert "warning: dumps: 2 particle(s) vanish" in err and "--outflow-z" in err
    whole = trajectory_from_dumps([write_dump(tmp_path / "all.liggghts", falling(STEPS))], [], 2e-5)
    assert whole.metadata["vanished"] == 0


def test_negative_numbers_in_e_notation_are_values_not_options(tmp_path, capsys):
    dump = write_dump(tmp_path / "dump.liggghts", falling(STEPS))
    before = hashlib.sha256(dump.read_bytes()).hexdigest()
    with pytest.raises(SystemExit) as info:
        convert_main([str(dump), "--dem-dt", "-2e-5", "--out", str(tmp_path / "t.h5")])
    assert info.value.code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and "-2e-05" in err[0] and "expected one argument" not in err[0], err
    out = convert_main(
        [str(dump), "--dem-dt", "2e-5", "--outflow-z", "-3e-2", "--out", str(tmp_path / "t.h5")]
    )
    assert out.is_file()
    assert hashlib.sha256(dump.read_bytes()).hexdigest() == before
