"""Sanity checks of the importer, each with a hand-made dump: units, huge coordinates,
non-finite values, a wrong time step, an output that would overwrite an input."""

from __future__ import annotations

import numpy as np
import pytest

from granular_pyg.dem_import import convert
from granular_pyg.dem_import.convert import trajectory_from_dumps
from granular_pyg.errors import InputError
from granular_pyg.io import read_trajectory
from tests.dem.dump_text import falling, plate, write_dump, write_stl

DT = 2e-5
STEPS = range(0, 2001, 125)


@pytest.fixture
def dump(tmp_path):
    return write_dump(tmp_path / "dump.liggghts", falling(STEPS))


def test_an_stl_in_millimetres_is_refused_pointing_at_units_mm(dump, tmp_path):
    stl = write_stl(tmp_path / "floor.stl", plate(z=-50.0, half=80.0))  # mm numbers
    with pytest.raises(InputError, match=r"wall floor .*spans 226.3 m.*--units mm"):
        trajectory_from_dumps(dump, [stl], dem_dt=DT)
    wall = trajectory_from_dumps(dump, [stl], dem_dt=DT, units="mm").scene.walls[0]
    assert wall.vertices[:, 2].tolist() == pytest.approx([-0.05] * 4)


def test_a_vertex_beyond_a_kilometre_is_refused(dump, tmp_path):
    stl = write_stl(tmp_path / "far.stl", plate(z=2000.0, half=0.04))
    with pytest.raises(InputError, match=r"wall far .*vertex 0 .*2000 m from the origin"):
        trajectory_from_dumps(dump, [stl], dem_dt=DT)


def test_nan_in_one_coordinate_of_an_atom_line_is_refused(tmp_path):
    frames = falling(STEPS)
    frames[3][2][4, 1] = np.nan
    dump = write_dump(tmp_path / "dump.liggghts", frames)
    with pytest.raises(InputError, match=r"TIMESTEP 375\): atom id 5 has a non-finite position"):
        trajectory_from_dumps(dump, dem_dt=DT)


def test_infinite_velocities_are_refused(tmp_path):
    frames = falling(STEPS)
    frames[2][3][7] = np.inf
    dump = write_dump(tmp_path / "dump.liggghts", frames)
    with pytest.raises(InputError, match=r"atom id 8 has a non-finite velocity.*vx = inf"):
        trajectory_from_dumps(dump, dem_dt=DT)


@pytest.mark.parametrize("factor", [10.0, 0.1])
def test_a_ten_times_wrong_time_step_is_refused_naming_the_implied_one(dump, factor):
    with pytest.raises(InputError, match=r"--dem-dt: a DEM time step of .* imply 2e-05 s"):
        trajectory_from_dumps(dump, dem_dt=DT * factor)


def test_the_right_time_step_passes(dump):
    assert trajectory_from_dumps(dump, dem_dt=DT).scene.dem_dt == DT


def _cli(dump, out, *more):
    return convert.main([str(dump), "--dem-dt", str(DT), "--out", str(out), *more])


@pytest.mark.parametrize("target", ["dump", "stl", "inside_folder"])
def test_an_output_that_is_an_input_is_refused(tmp_path, capsys, target):
    folder = tmp_path / "dumps"
    folder.mkdir()
    dump = write_dump(folder / "dump.liggghts", falling(STEPS))
    stl = write_stl(tmp_path / "floor.stl", plate(z=0.0))
    out = {"dump": dump, "stl": stl, "inside_folder": folder / "traj.h5"}[target]
    before = {p: p.read_bytes() for p in (dump, stl)}
    with pytest.raises(SystemExit):
        _cli(folder, out, "--stl", str(stl), "--overwrite")
    assert "is the input" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in (dump, stl)} == before


def test_an_existing_output_needs_overwrite(dump, tmp_path, capsys):
    out = tmp_path / "traj.h5"
    _cli(dump, out)
    with pytest.raises(SystemExit):
        _cli(dump, out)
    assert "exists" in capsys.readouterr().err
    _cli(dump, out, "--overwrite")
    assert read_trajectory(out).num_frames == len(STEPS)
