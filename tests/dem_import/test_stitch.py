"""Stitching several dump files: time-step order, duplicates, gaps."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from granular_pyg.dem_import.stitch import evenly_spaced_runs, read_dump_runs, read_dumps
from granular_pyg.errors import InputError
from tests.dem.dump_text import falling, write_dump


def _parts(tmp_path, *ranges):
    return [
        write_dump(tmp_path / f"part{k}.dump", falling(steps)) for k, steps in enumerate(ranges)
    ]


def test_files_are_merged_in_timestep_order_whatever_their_order(tmp_path):
    fill, discharge = _parts(tmp_path, range(0, 500, 100), range(500, 900, 100))
    frames = read_dumps([discharge, fill])
    assert [f.timestep for f in frames] == list(range(0, 900, 100))


def test_an_identical_duplicate_step_at_the_boundary_is_kept_once(tmp_path):
    fill, discharge = _parts(tmp_path, range(0, 600, 100), range(500, 900, 100))
    frames = read_dumps([fill, discharge])
    assert [f.timestep for f in frames] == list(range(0, 900, 100))
    assert frames[5].source == str(fill)


def test_a_duplicate_step_with_other_values_is_refused(tmp_path):
    fill = write_dump(tmp_path / "fill.dump", falling(range(0, 600, 100)))
    other = write_dump(tmp_path / "other.dump", falling(range(500, 900, 100), seed=1))
    with pytest.raises(InputError, match=r"TIMESTEP 500 is written twice.*different values"):
        read_dumps([fill, other])


def test_a_duplicate_step_with_other_atoms_is_refused(tmp_path):
    fill = write_dump(tmp_path / "fill.dump", falling(range(0, 600, 100)))
    other = write_dump(tmp_path / "other.dump", falling(range(500, 900, 100), n=19))
    with pytest.raises(InputError, match=r"TIMESTEP 500 is written twice.*different atoms"):
        read_dumps([fill, other])


def test_a_gap_is_refused_naming_the_timesteps(tmp_path):
    fill, discharge = _parts(tmp_path, range(0, 500, 100), range(700, 900, 100))
    with pytest.raises(InputError, match=r"TIMESTEP 400 .* -> 700 .*2 frame\(s\) missing"):
        read_dumps([fill, discharge])


def test_uneven_spacing_is_refused(tmp_path):
    dump = write_dump(tmp_path / "d.dump", falling([0, 100, 200, 250, 350, 450]))
    with pytest.raises(InputError, match=r"every 100 steps.*200 .* -> 250 .*a step of 50"):
        read_dumps(dump)


def test_files_and_folders_mix(tmp_path):
    folder = tmp_path / "discharge"
    folder.mkdir()
    for step in (500, 600, 700):
        write_dump(folder / f"dump{step}.liggghts", falling([step]))
    fill = write_dump(tmp_path / "fill.dump", falling(range(0, 600, 100)))
    frames = read_dumps([fill, folder], pattern="dump*.liggghts")
    assert [f.timestep for f in frames] == list(range(0, 800, 100))


def test_a_gap_refusal_names_the_split_gaps_option(tmp_path):
    fill, discharge = _parts(tmp_path, range(0, 500, 100), range(700, 900, 100))
    with pytest.raises(InputError, match=r"or pass --split-gaps to write each evenly spaced run"):
        read_dumps([fill, discharge])


def test_read_dump_runs_cuts_at_the_gap(tmp_path):
    fill, discharge = _parts(tmp_path, range(0, 500, 100), range(700, 900, 100))
    runs = read_dump_runs([discharge, fill])
    assert [[f.timestep for f in run] for run in runs] == [[0, 100, 200, 300, 400], [700, 800]]


def _steps(*timesteps):
    return [SimpleNamespace(timestep=t) for t in timesteps]


@pytest.mark.parametrize(
    ("timesteps", "expected"),
    [
        ((0, 100, 200), [[0, 100, 200]]),
        ((0, 100, 200, 500, 600), [[0, 100, 200], [500, 600]]),
        ((0, 100, 200, 250, 350, 450), [[0, 100, 200], [250, 350, 450]]),
        ((0, 1000, 2000, 2125, 2250, 2375), [[0, 1000, 2000], [2125, 2250, 2375]]),
        ((700, 1000, 1100, 1200), [[700], [1000, 1100, 1200]]),
        ((0, 100, 300, 400, 600, 700), [[0, 100], [300, 400], [600, 700]]),
        ((5,), [[5]]),
        ((), []),
    ],
)
def test_evenly_spaced_runs(timesteps, expected):
    runs = evenly_spaced_runs(_steps(*timesteps))
    assert [[f.timestep for f in run] for run in runs] == expected
