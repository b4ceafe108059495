"""The LIGGGHTS ``dump custom`` parser: frames, deleted atoms, truncation, errors."""

from __future__ import annotations

import numpy as np
import pytest

from granular_pyg.dem.dump import DumpFrame, frames_to_arrays, read_dump
from granular_pyg.errors import InputError

COLUMNS = "id type x y z vx vy vz radius"


def _frame(timestep: int, atoms: list[tuple], columns: str = COLUMNS) -> str:
    lines = [
        "ITEM: TIMESTEP",
        str(timestep),
        "ITEM: NUMBER OF ATOMS",
        str(len(atoms)),
        "ITEM: BOX BOUNDS ff ff ff",
        "-0.05 0.05",
        "-0.02 0.02",
        "-0.01 0.2",
        f"ITEM: ATOMS {columns}",
        *(" ".join(str(v) for v in atom) for atom in atoms),
    ]
    return "\n".join(lines) + "\n"


def _atom(atom_id: int, step: int) -> tuple:
    """One atom line whose values encode id and step, radius 1 mm + id um."""
    z = 0.1 - 0.001 * step + 0.01 * atom_id
    return (atom_id, 1, 0.001 * atom_id, 0.0, z, 0.0, 0.0, -0.1 * step, 0.001 + 1e-6 * atom_id)


# Three frames; ids listed unsorted; atom 2 is deleted from the second frame on.
FRAMES = [
    (0, [3, 1, 2]),
    (125, [1, 3]),
    (250, [3, 1]),
]
TEXT = "".join(_frame(step, [_atom(i, k) for i in ids]) for k, (step, ids) in enumerate(FRAMES))


def _write(tmp_path, text: str, name: str = "dump.liggghts", newline: str = "\n"):
    path = tmp_path / name
    path.write_bytes(text.replace("\n", newline).encode())
    return path


def test_reads_every_frame_of_a_multi_frame_file(tmp_path):
    frames = read_dump(_write(tmp_path, TEXT))
    assert [(f.timestep, f.num_atoms) for f in frames] == [(0, 3), (125, 2), (250, 2)]


def test_frame_keeps_box_and_columns(tmp_path):
    frame = read_dump(_write(tmp_path, TEXT))[0]
    assert (frame.box.tolist(), frame.columns) == (
        [[-0.05, 0.05], [-0.02, 0.02], [-0.01, 0.2]],
        COLUMNS.split(),
    )


def test_column_returns_values_by_name(tmp_path):
    frame = read_dump(_write(tmp_path, TEXT))[0]
    assert frame.column("id").tolist() == [3.0, 1.0, 2.0]


def test_unknown_column_raises_naming_it(tmp_path):
    frame = read_dump(_write(tmp_path, TEXT))[0]
    with pytest.raises(InputError, match="no column 'omegax'"):
        frame.column("omegax")


def test_arrays_are_sorted_by_id(tmp_path):
    arrays = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    expected_x = np.array([0.001, 0.002, 0.003], np.float32)
    assert (arrays["ids"].tolist(), arrays["positions"][0, :, 0].tolist()) == (
        [1, 2, 3],
        expected_x.tolist(),
    )


def test_arrays_have_the_documented_dtypes_and_shapes(tmp_path):
    arrays = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    summary = {k: (v.dtype, v.shape) for k, v in arrays.items() if isinstance(v, np.ndarray)}
    assert summary == {
        "positions": (np.float32, (3, 3, 3)),
        "velocities": (np.float32, (3, 3, 3)),
        "radii": (np.float32, (3,)),
        "ids": (np.int64, (3,)),
        "times": (np.float64, (3,)),
    }


def test_values_land_in_their_atom_slot(tmp_path):
    arrays = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    expected = np.array([_atom(3, 2)[2:5], _atom(3, 2)[5:8]], np.float32)
    assert np.array_equal(
        np.stack([arrays["positions"][2, 2], arrays["velocities"][2, 2]]), expected
    )


def test_deleted_atom_is_nan_from_that_frame_on(tmp_path):
    arrays = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    present = np.isfinite(arrays["positions"]).all(axis=2)
    assert present[:, 1].tolist() == [True, False, False]


def test_deleted_atom_has_nan_velocity_too(tmp_path):
    arrays = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    assert np.isnan(arrays["velocities"][1:, 1]).all()


def test_radii_come_from_first_appearance(tmp_path):
    arrays = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    assert arrays["radii"].tolist() == np.array([0.001001, 0.001002, 0.001003], np.float32).tolist()


def test_times_count_from_the_first_timestep(tmp_path):
    text = "".join(_frame(1000 + 125 * k, [_atom(1, k)]) for k in range(3))
    arrays = frames_to_arrays(read_dump(_write(tmp_path, text)), dem_dt=2e-5)
    assert (arrays["times"].tolist(), arrays["first_timestep"]) == ([0.0, 0.0025, 0.005], 1000)


def test_truncated_last_frame_warns_with_file_and_line_and_is_dropped(tmp_path):
    cut = TEXT.rstrip("\n").rsplit("\n", 1)[0] + "\n"  # last frame loses its last atom line
    path = _write(tmp_path, cut)
    with pytest.warns(UserWarning, match=r"dump\.liggghts:\d+.*truncated") as record:
        frames = read_dump(path)
    lines = cut.splitlines()
    line = max(k for k, text in enumerate(lines) if text.startswith("ITEM: ATOMS")) + 1
    assert (len(frames), f"dump.liggghts:{line}" in str(record[0].message)) == (2, True)


def test_truncated_last_frame_raises_when_asked(tmp_path):
    cut = TEXT.rstrip("\n").rsplit("\n", 1)[0] + "\n"
    with pytest.raises(InputError, match=r"dump\.liggghts:\d+.*truncated"):
        read_dump(_write(tmp_path, cut), on_truncated="raise")


def test_line_cut_in_the_middle_counts_as_truncation(tmp_path):
    cut = TEXT[: TEXT.rindex(" ") - 6]  # the last atom line loses its last values
    with pytest.warns(UserWarning, match="truncated"):
        frames = read_dump(_write(tmp_path, cut))
    assert len(frames) == 2


@pytest.mark.parametrize(
    "marker", ["ITEM: NUMBER OF ATOMS\n", "ITEM: BOX BOUNDS ff ff ff\n-0.05", "ITEM: ATOMS", "IT"]
)
def test_frame_cut_inside_its_header_is_dropped(tmp_path, marker):
    last = _frame(375, [_atom(1, 3), _atom(3, 3)])
    cut = TEXT + last[: last.index(marker) + len(marker)]
    with pytest.warns(UserWarning, match=r"dump\.liggghts:\d+"):
        frames = read_dump(_write(tmp_path, cut))
    assert [f.timestep for f in frames] == [0, 125, 250]


def test_short_frame_in_the_middle_is_an_error_not_truncation(tmp_path):
    broken = _frame(0, [_atom(1, 0)]).replace(
        "ITEM: NUMBER OF ATOMS\n1", "ITEM: NUMBER OF ATOMS\n2"
    )
    text = broken + _frame(125, [_atom(1, 1)])
    with pytest.raises(InputError, match=r"dump\.liggghts:9: TIMESTEP 0 lists 1 atom line"):
        read_dump(_write(tmp_path, text))


def test_crlf_file_gives_identical_arrays(tmp_path):
    lf = frames_to_arrays(read_dump(_write(tmp_path, TEXT, "lf.dump")), dem_dt=2e-5)
    crlf = frames_to_arrays(read_dump(_write(tmp_path, TEXT, "crlf.dump", "\r\n")), dem_dt=2e-5)
    assert all(
        np.array_equal(lf[k], crlf[k], equal_nan=True)
        for k in ("positions", "velocities", "radii", "ids", "times")
    )


def test_blank_trailing_lines_are_ignored(tmp_path):
    frames = read_dump(_write(tmp_path, TEXT + "\n\n  \n"))
    assert [f.num_atoms for f in frames] == [3, 2, 2]


def test_folder_of_one_file_per_frame_equals_the_multi_frame_file(tmp_path):
    single = frames_to_arrays(read_dump(_write(tmp_path, TEXT)), dem_dt=2e-5)
    folder = tmp_path / "post"
    folder.mkdir()
    # names sort as strings in the wrong order (dump1000 < dump125 < dump250 < dump0 is not the
    # timestep order); the reader must order by each file's first TIMESTEP
    for k, (step, ids) in enumerate(FRAMES):
        (folder / f"dump{step}.liggghts").write_text(_frame(step, [_atom(i, k) for i in ids]))
    per_file = frames_to_arrays(read_dump(folder), dem_dt=2e-5)
    assert all(
        np.array_equal(single[k], per_file[k], equal_nan=True)
        for k in ("positions", "velocities", "radii", "ids", "times")
    )


def test_folder_pattern_selects_dump_files(tmp_path):
    for k, (step, ids) in enumerate(FRAMES):
        (tmp_path / f"dump{step}.liggghts").write_text(_frame(step, [_atom(i, k) for i in ids]))
    (tmp_path / "log.liggghts").write_text("LIGGGHTS (Version 3.8.0)\n")
    frames = read_dump(tmp_path, pattern="dump*.liggghts")
    assert [f.timestep for f in frames] == [0, 125, 250]


def test_non_numeric_value_raises_with_its_line(tmp_path):
    bad = TEXT.replace("0.003 0.0 0.13", "0.003 abc 0.13", 1)
    line = bad.splitlines().index(next(s for s in bad.splitlines() if "abc" in s)) + 1
    with pytest.raises(InputError, match=rf"dump\.liggghts:{line}: column 'y' holds 'abc'"):
        read_dump(_write(tmp_path, bad))


def test_wrong_column_count_raises_with_its_line(tmp_path):
    lines = TEXT.splitlines()
    lines[10] = lines[10] + " 7"  # second atom line of the first frame gets a tenth value
    with pytest.raises(InputError, match=r"dump\.liggghts:11: expected 9 values"):
        read_dump(_write(tmp_path, "\n".join(lines) + "\n"))


def test_missing_id_column_raises(tmp_path):
    text = _frame(0, [(1, 0.0, 0.0, 0.1)], columns="type x y z")
    with pytest.raises(InputError, match=r"dump\.liggghts:9: .* has no 'id' column"):
        read_dump(_write(tmp_path, text))


def test_missing_velocity_column_raises_in_frames_to_arrays(tmp_path):
    text = _frame(0, [(1, 1, 0.0, 0.0, 0.1, 0.001)], columns="id type x y z radius")
    frames = read_dump(_write(tmp_path, text))
    with pytest.raises(InputError, match=r"missing column\(s\) \['vx', 'vy', 'vz'\]"):
        frames_to_arrays(frames, dem_dt=2e-5)


def test_decreasing_timesteps_raise(tmp_path):
    text = _frame(125, [_atom(1, 0)]) + _frame(0, [_atom(1, 1)])
    with pytest.raises(InputError, match="strictly increasing timesteps"):
        frames_to_arrays(read_dump(_write(tmp_path, text)), dem_dt=2e-5)


def test_duplicate_ids_in_a_frame_raise(tmp_path):
    text = _frame(0, [_atom(1, 0), _atom(1, 0)])
    with pytest.raises(InputError, match="duplicate atom ids"):
        frames_to_arrays(read_dump(_write(tmp_path, text)), dem_dt=2e-5)


def test_not_a_dump_file_raises(tmp_path):
    with pytest.raises(InputError, match=r"notes\.txt:1: no 'ITEM:' header"):
        read_dump(_write(tmp_path, "hello\nworld\n", "notes.txt"))


def test_missing_path_raises_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere"):
        read_dump(tmp_path / "nothere")


def test_empty_frames_list_raises():
    with pytest.raises(InputError, match="frames: empty"):
        frames_to_arrays([], dem_dt=2e-5)


def test_dump_frame_column_helper_on_a_hand_made_frame():
    frame = DumpFrame(0, np.zeros((3, 2)), ["id", "x"], np.array([[2.0, 0.5], [1.0, 0.25]]))
    assert frame.column("x").tolist() == [0.5, 0.25]


def test_large_shuffled_dump_is_parsed_exactly(tmp_path):
    """2,000 atoms x 50 frames, ids shuffled per frame: every value lands on its own id."""
    rng = np.random.default_rng(0)
    num_atoms, num_frames = 2000, 50
    values = np.round(rng.normal(size=(num_frames, num_atoms, 6)), 6)
    frames = []
    for k in range(num_frames):
        order = rng.permutation(num_atoms)
        body = "\n".join(
            f"{i + 1} 1 " + " ".join(f"{v:.6f}" for v in values[k, i]) + " 0.0015" for i in order
        )
        frames.append(
            f"ITEM: TIMESTEP\n{125 * k}\nITEM: NUMBER OF ATOMS\n{num_atoms}\n"
            f"ITEM: BOX BOUNDS ff ff ff\n0 1\n0 1\n0 1\nITEM: ATOMS {COLUMNS}\n{body}\n"
        )
    arrays = frames_to_arrays(read_dump(_write(tmp_path, "".join(frames))), dem_dt=2e-5)
    np.testing.assert_array_equal(arrays["positions"], values[..., :3].astype(np.float32))
    np.testing.assert_array_equal(arrays["velocities"], values[..., 3:].astype(np.float32))
    np.testing.assert_array_equal(arrays["ids"], np.arange(1, num_atoms + 1))
