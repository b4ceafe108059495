"""Importing a user's LIGGGHTS run: dumps + STL walls -> Trajectory and HDF5 file."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from granular_pyg.dem_import import convert
from granular_pyg.dem_import.convert import (
    load_stl_wall,
    trajectories_from_dumps,
    trajectory_from_dumps,
)
from granular_pyg.errors import InputError
from granular_pyg.io import read_trajectory
from granular_pyg.scenes.scene import WallMotion
from tests.dem.dump_text import falling, plate, write_dump, write_mesh_dump, write_stl

DUMP = """\
ITEM: TIMESTEP
1000
ITEM: NUMBER OF ATOMS
3
ITEM: BOX BOUNDS ff ff ff
-0.05 0.05
-0.02 0.02
-0.01 0.2
ITEM: ATOMS id type x y z vx vy vz radius
3 1 0.01 0.0 0.05 0 0 -0.1 0.0015
1 1 -0.01 0.005 0.03 0 0 -0.1 0.0015
2 1 0.0 -0.005 0.04 0 0 -0.1 0.002
ITEM: TIMESTEP
1125
ITEM: NUMBER OF ATOMS
2
ITEM: BOX BOUNDS ff ff ff
-0.05 0.05
-0.02 0.02
-0.01 0.2
ITEM: ATOMS id type x y z vx vy vz radius
1 1 -0.01 0.005 0.0297 0 0 -0.12 0.0015
3 1 0.01 0.0 0.0497 0 0 -0.12 0.0015
"""


@pytest.fixture
def run(tmp_path):
    """A dump file, an ASCII STL box (12 triangles) and a binary STL plate (2 triangles)."""
    dump = tmp_path / "dump.liggghts"
    dump.write_text(DUMP)
    box = trimesh.creation.box(extents=(0.08, 0.03, 0.15))
    ascii_stl = tmp_path / "hopper-walls.stl"
    box.export(ascii_stl, file_type="stl_ascii")
    plate = trimesh.Trimesh(
        vertices=[[-0.04, -0.015, 0.0], [0.04, -0.015, 0.0], [0.04, 0.015, 0.0], [-0.04, 0.015, 0]],
        faces=[[0, 1, 2], [0, 2, 3]],
    )
    binary_stl = tmp_path / "lid.stl"
    plate.export(binary_stl, file_type="stl")
    return dump, [ascii_stl, binary_stl]


def test_stl_files_become_walls_with_their_triangle_counts(run):
    dump, stls = run
    traj = trajectory_from_dumps(dump, stls, dem_dt=2e-5)
    assert [(w.name, len(w.faces)) for w in traj.scene.walls] == [("hopper_walls", 12), ("lid", 2)]


def test_stl_triangles_keep_their_corners(run):
    _, stls = run
    wall = load_stl_wall(stls[1], "lid")
    expected = trimesh.load(stls[1], force="mesh", process=False).triangles
    assert np.array_equal(wall.triangles, expected)


def test_ascii_and_binary_stl_are_both_read(run):
    _, stls = run
    first_bytes = [p.read_bytes()[:5] for p in stls]
    walls = [load_stl_wall(p, "w") for p in stls]
    assert (first_bytes[0], first_bytes[1] != b"solid", [len(w.faces) for w in walls]) == (
        b"solid",
        True,
        [12, 2],
    )


def test_trajectory_holds_the_dump_particles(run):
    dump, stls = run
    traj = trajectory_from_dumps(dump, stls, dem_dt=2e-5)
    summary = (traj.ids.tolist(), traj.times.tolist(), traj.present[:, 1].tolist())
    assert summary == ([1, 2, 3], [0.0, 125 * 2e-5], [True, False])


def test_scene_describes_the_run(run):
    dump, stls = run
    scene = trajectory_from_dumps(dump, stls, dem_dt=2e-5, outflow_z=-0.005).scene
    summary = (
        scene.name,
        scene.particles.count,
        scene.particles.radius,
        scene.particles.fill_lo,
        scene.particles.fill_hi,
        scene.domain_lo,
        scene.domain_hi,
        scene.outflow_z,
        scene.settle_time,
    )
    assert summary == (
        "imported",
        3,
        pytest.approx(0.002),
        (-0.01, -0.005, 0.03),
        (0.01, 0.005, 0.05),
        (-0.05, -0.02, -0.005),
        (0.05, 0.02, 0.2),
        -0.005,
        0.0,
    )


def test_scene_times_are_multiples_of_the_dem_step(run):
    dump, stls = run
    scene = trajectory_from_dumps(dump, stls, dem_dt=2e-5).scene
    assert (scene.frame_dt, scene.duration) == (pytest.approx(2.5e-3), pytest.approx(2.5e-3))


def test_metadata_records_the_source(run):
    dump, stls = run
    metadata = trajectory_from_dumps(dump, stls, dem_dt=2e-5).metadata
    assert (metadata["source"], metadata["dumps"], metadata["first_timestep"]) == (
        "imported",
        [str(dump)],
        1000,
    )


def test_outflow_above_the_box_raises(run):
    dump, stls = run
    with pytest.raises(InputError, match="outflow_z"):
        trajectory_from_dumps(dump, stls, dem_dt=2e-5, outflow_z=1.0)


def test_empty_stl_raises(run, tmp_path):
    dump, _ = run
    empty = tmp_path / "empty.stl"
    empty.write_text("solid empty\nendsolid empty\n")
    with pytest.raises(InputError, match=r"empty\.stl"):
        trajectory_from_dumps(dump, [empty], dem_dt=2e-5)


def test_duplicate_stems_get_unique_wall_names(run, tmp_path):
    dump, stls = run
    other = tmp_path / "sub"
    other.mkdir()
    (other / "lid.stl").write_bytes(stls[1].read_bytes())
    traj = trajectory_from_dumps(dump, [stls[1], other / "lid.stl"], dem_dt=2e-5)
    assert [w.name for w in traj.scene.walls] == ["lid", "lid_2"]


def test_cli_writes_a_trajectory_file(run, tmp_path, capsys):
    dump, stls = run
    out = tmp_path / "traj.h5"
    convert.main([str(dump), "--stl", *map(str, stls), "--dem-dt", "2e-5", "--out", str(out)])
    traj = read_trajectory(out)
    assert (traj.num_frames, traj.num_particles, len(traj.scene.walls)) == (2, 3, 2)


def test_cli_prints_a_one_line_summary(run, tmp_path, capsys):
    dump, stls = run
    convert.main(
        [str(dump), "--stl", *map(str, stls), "--dem-dt", "2e-5", "--out", str(tmp_path) + "/t.h5"]
    )
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "2 frames x 3 particles" in out


def test_a_missing_time_step_says_where_to_give_it(run):
    dump, stls = run
    with pytest.raises(InputError, match=r"--dem-dt: the run's DEM time step .*--input/--log"):
        trajectory_from_dumps(dump, stls)


def test_walls_yaml_gives_motions_removals_units_kind_and_materials(run, tmp_path):
    dump, stls = run
    mm = tmp_path / "lid_mm.stl"
    trimesh.load(stls[1], force="mesh", process=False).apply_scale(1000).export(mm)
    walls = tmp_path / "walls.yaml"
    walls.write_text(
        "kind: drum\n"
        "gravity: [0, 0, -9.7]\n"
        "materials: {youngs_modulus: 5.0e6, density: 1200}\n"
        "walls:\n"
        "  hopper-walls.stl:\n"
        "    motion: {kind: rotation, axis: [0, 1, 0], omega: 2.0, start_time: 0.001}\n"
        "  lid_mm.stl:\n"
        "    name: lid\n"
        "    units: mm\n"
        "    removal_time: 0.0025\n"
    )
    scene = trajectory_from_dumps(dump, [stls[0]], dem_dt=2e-5, walls=walls).scene
    box, lid = scene.walls
    assert (box.motion.kind, box.motion.omega, box.motion.start_time) == ("rotation", 2.0, 0.001)
    assert (lid.name, lid.removal_time) == ("lid", 0.0025)
    np.testing.assert_allclose(lid.vertices[:, 0].max(), 0.04)
    assert (scene.kind, scene.name, scene.gravity) == ("drum", "drum", (0.0, 0.0, -9.7))
    assert (scene.materials.youngs_modulus, scene.materials.density) == (5e6, 1200.0)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("walls:\n  lid.stl:\n    removal: 1.0\n", r"walls\[lid.stl\]: unknown key.*removal"),
        ("walls:\n  lid.stl: {units: inch}\n", "units 'inch'"),
        ("walls:\n  lid.stl:\n    motion: {kind: spin}\n", "motion.kind"),
        ("kind: silo\n", "kind 'silo'"),
        ("materials: {density: heavy}\n", "materials.density: expected a number"),
    ],
)
def test_walls_yaml_mistakes_are_named(run, tmp_path, text, message):
    dump, stls = run
    walls = tmp_path / "walls.yaml"
    walls.write_text(text)
    with pytest.raises(InputError, match=message):
        trajectory_from_dumps(dump, stls, dem_dt=2e-5, walls=walls)


def test_cli_takes_several_dumps_kind_and_units(run, tmp_path, capsys):
    dump, stls = run
    second = tmp_path / "more.liggghts"
    last = DUMP[DUMP.index("ITEM: TIMESTEP", 1) :]  # the frame at 1125, again at 1250
    second.write_text(last + last.replace("\n1125\n", "\n1250\n", 1))
    out = tmp_path / "t.h5"
    argv = [str(dump), str(second), "--stl", *map(str, stls), "--dem-dt", "2e-5"]
    convert.main([*argv, "--out", str(out), "--kind", "hopper", "--units", "m"])
    traj = read_trajectory(out)
    assert (traj.num_frames, traj.scene.kind) == (3, "hopper")


def test_cli_reports_bad_input_without_a_traceback(tmp_path, capsys):
    with pytest.raises(SystemExit):
        convert.main([str(tmp_path / "missing"), "--dem-dt", "2e-5", "--out", "x.h5"])
    assert "no such dump file" in capsys.readouterr().err


def test_python_dash_m_entry_point_runs(run, tmp_path):
    dump, stls = run
    out = tmp_path / "cli.h5"
    args = [str(dump), "--stl", *map(str, stls), "--dem-dt", "2e-5", "--out", str(out)]
    command = [sys.executable, "-m", "granular_pyg.dem_import.convert", *args]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    assert (result.returncode, read_trajectory(out).num_frames) == (0, 2), result.stderr


# --- --split-gaps: one trajectory per evenly spaced run ---------------------------------------

GAP_DT = 2e-5


@pytest.fixture
def gap_run(tmp_path):
    """A dump folder, one file per frame, TIMESTEPs 0..500 and 700..1000 every 100 (600 is
    missing), of 4 particles in free fall; and the frames as written."""
    folder = tmp_path / "dumps"
    folder.mkdir()
    frames = falling([*range(0, 600, 100), *range(700, 1100, 100)], n=4, dem_dt=GAP_DT)
    for frame in frames:
        write_dump(folder / f"dump{frame[0]}.liggghts", [frame])
    return folder, frames


def _sha256(folder):
    """SHA-256 of every file in ``folder`` (not in its subfolders), by name."""
    files = sorted(p for p in folder.iterdir() if p.is_file())
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def _convert(folder, out, *extra):
    return convert.main([str(folder), "--dem-dt", str(GAP_DT), "--out", str(out), *extra])


def test_a_gap_is_refused_without_split_gaps_naming_the_timesteps_and_the_option(
    gap_run, tmp_path, capsys
):
    folder, _ = gap_run
    with pytest.raises(SystemExit) as exit_info:
        _convert(folder, tmp_path / "run.h5")
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "TIMESTEP 500" in err and "-> 700" in err and "1 frame(s) missing" in err
    assert "--split-gaps" in err
    assert not (tmp_path / "run.h5").exists()


def test_split_gaps_writes_one_trajectory_per_run_with_the_dump_positions(gap_run, tmp_path):
    folder, frames = gap_run
    before = _sha256(folder)
    outs = _convert(folder, tmp_path / "run.h5", "--split-gaps")
    assert outs == [tmp_path / "run_part0.h5", tmp_path / "run_part1.h5"]
    assert not (tmp_path / "run.h5").exists()
    for out, written in zip(outs, (frames[:6], frames[6:]), strict=True):
        traj = read_trajectory(out)
        first = written[0][0]
        assert traj.ids.tolist() == [1, 2, 3, 4]
        assert traj.metadata["first_timestep"] == first
        assert traj.metadata["split"]["timesteps"] == [first, written[-1][0]]
        expected = np.stack([p for _, _, p, _ in written]).astype(np.float32)
        assert np.array_equal(traj.positions, expected)
        assert traj.times.tolist() == [(s - first) * GAP_DT for s, *_ in written]
        assert traj.scene.frame_dt == pytest.approx(100 * GAP_DT)
    assert _sha256(folder) == before


def test_split_gaps_summary_lists_every_part_and_warns_about_short_parts(gap_run, tmp_path, capsys):
    folder, _ = gap_run
    _convert(folder, tmp_path / "run.h5", "--split-gaps")
    captured = capsys.readouterr()
    assert captured.out.count("\n") == 1
    assert "wrote 2 part(s)" in captured.out
    assert f"{tmp_path / 'run_part0.h5'}: 6 frames x 4 particles, TIMESTEPs 0..500" in captured.out
    assert f"{tmp_path / 'run_part1.h5'}: 4 frames x 4 particles, TIMESTEPs 700..1000" in (
        captured.out
    )
    warnings = [line for line in captured.err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1
    assert "run_part1.h5 (4 frames)" in warnings[0] and "run_part0" not in warnings[0]


def test_split_gaps_skips_runs_shorter_than_three_frames_with_one_warning(tmp_path, capsys):
    steps = [*range(0, 600, 100), 700, 800, *range(1000, 1300, 100)]
    dump = write_dump(tmp_path / "run.dump", falling(steps, n=3, dem_dt=GAP_DT))
    outs = _convert(dump, tmp_path / "out" / "run.h5", "--split-gaps")
    err = capsys.readouterr().err
    assert [read_trajectory(out).metadata["first_timestep"] for out in outs] == [0, 1000]
    skipped = [line for line in err.splitlines() if "skipped" in line]
    assert skipped == [
        "warning: --split-gaps: skipped 1 run(s) of evenly spaced frames shorter than 3 "
        "frames: TIMESTEPs 700..800 (2 frames)"
    ]
    assert not (tmp_path / "out" / "run_part2.h5").exists()


def test_split_gaps_refuses_an_existing_part_without_overwrite(gap_run, tmp_path, capsys):
    folder, _ = gap_run
    outs = _convert(folder, tmp_path / "run.h5", "--split-gaps")
    written = _sha256(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        _convert(folder, tmp_path / "run.h5", "--split-gaps")
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert f"{outs[0]} exists" in err and "--overwrite" in err
    assert _sha256(tmp_path) == written
    assert _convert(folder, tmp_path / "run.h5", "--split-gaps", "--overwrite") == outs


def test_split_gaps_never_writes_a_part_into_an_input_folder(gap_run, capsys):
    folder, _ = gap_run
    before = _sha256(folder)
    with pytest.raises(SystemExit):
        _convert(folder, folder / "run.h5", "--split-gaps")
    assert "is the input" in capsys.readouterr().err
    assert _sha256(folder) == before


def test_split_gaps_rebases_the_walls_on_each_part(gap_run, tmp_path):
    folder, _ = gap_run
    write_stl(tmp_path / "turntable.stl", plate(0.0))
    write_stl(tmp_path / "lid.stl", plate(0.18))
    walls = tmp_path / "walls.yaml"
    walls.write_text(
        "walls:\n"
        "  turntable.stl:\n"
        "    motion: {kind: rotation, axis: [0, 0, 1], omega: 2.0}\n"
        "  lid.stl:\n"
        "    removal_time: 0.012\n"  # TIMESTEP 600, in the gap
    )
    result = trajectories_from_dumps(folder, dem_dt=GAP_DT, walls=walls)
    first, second = (t.scene for t in result.parts)
    assert [w.name for w in first.walls] == ["turntable", "lid"]
    assert first.walls[1].removal_time == pytest.approx(0.012)
    assert [w.name for w in second.walls] == ["turntable"]
    offset = 700 * GAP_DT
    rot, shift = WallMotion("rotation", axis=(0, 0, 1), omega=2.0).pose(offset)
    np.testing.assert_allclose(second.walls[0].triangles, plate(0.0).triangles @ rot.T + shift)
    assert (second.walls[0].motion.kind, second.walls[0].motion.start_time) == ("rotation", 0.0)
    assert result.parts[1].metadata["split"]["offset"] == pytest.approx(offset)
    assert result.skipped == []


def test_split_gaps_takes_each_parts_walls_from_the_mesh_dumps(tmp_path):
    """Particle frames every 125 steps with 625 and 750 missing; mesh dumps every 125 steps of
    a spinning box and a plate gone from TIMESTEP 750 (in the gap)."""
    box_mesh = trimesh.creation.box(extents=(0.06, 0.03, 0.04))
    plate_mesh = plate(z=-0.03)
    spin = WallMotion("rotation", axis=(0, 0, 1), origin=(0.005, 0.0, 0.0), omega=3.0)
    steps = [*range(0, 625, 125), *range(875, 1375, 125)]
    dump = write_dump(tmp_path / "dump.liggghts", falling(steps, dem_dt=GAP_DT))
    meshes = tmp_path / "mesh"
    meshes.mkdir()
    for step in range(0, 1375, 125):
        rot, shift = spin.pose(step * GAP_DT)
        tris = [box_mesh.triangles @ rot.T + shift] + ([plate_mesh.triangles] if step < 750 else [])
        write_mesh_dump(meshes / f"mesh{step}.stl", np.concatenate(tris))
    stls = [
        write_stl(tmp_path / "box.stl", box_mesh),
        write_stl(tmp_path / "plate.stl", plate_mesh),
    ]
    result = trajectories_from_dumps(dump, stls, dem_dt=GAP_DT, mesh_dumps=[meshes])
    first, second = (t.scene for t in result.parts)
    assert [w.name for w in first.walls] == ["box", "plate"]
    assert first.walls[1].removal_time == pytest.approx(750 * GAP_DT, abs=1e-15)
    assert [w.name for w in second.walls] == ["box"]
    box = second.walls[0]
    assert (box.motion.kind, box.motion.start_time) == ("rotation", 0.0)
    for t in (0.0, 0.005):
        rot, shift = spin.pose(t + 875 * GAP_DT)
        np.testing.assert_allclose(box.vertices_at(t), box_mesh.vertices @ rot.T + shift, atol=2e-6)
