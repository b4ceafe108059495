"""Importing real tiny LIGGGHTS runs: a drum whose rotation is read from its ``dump mesh/stl``
files, and a hopper whose fill and discharge are two dump files with the lid removed between
them (each run about a second)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from granular_pyg.dem.dump import frames_to_arrays
from granular_pyg.dem.liggghts import find_liggghts, render_input, write_ascii_stl
from granular_pyg.dem_import import convert
from granular_pyg.dem_import.convert import trajectory_from_dumps
from granular_pyg.dem_import.mesh_dump import read_mesh_dumps
from granular_pyg.dem_import.stitch import read_dumps
from granular_pyg.io import read_trajectory
from granular_pyg.scenes import make_drum, make_hopper

COLUMNS = "id type x y z vx vy vz radius"
OMEGA = 2.0


def _run(workdir, scene, lines, name):
    for wall in scene.walls:
        write_ascii_stl(wall, workdir / f"{wall.name}.stl")
    (workdir / "post").mkdir()
    (workdir / f"in.{name}").write_text("\n".join(lines) + "\n")
    subprocess.run(
        [find_liggghts(), "-in", f"in.{name}", "-log", f"log.{name}"],
        cwd=workdir,
        check=True,
        capture_output=True,
    )
    return workdir


@pytest.fixture(scope="module")
def drum(tmp_path_factory):
    """200 particles in a 24-sided drum turning at 2 rad/s for 0.2 s, meshes dumped every
    250 steps (41 files)."""
    scene = make_drum(omega=OMEGA, num_particles=200, sections=24, settle_time=0.05, duration=0.2)
    lines = render_input(scene, seed=1).splitlines()
    at = lines.index("dump_modify dmp sort id")
    lines[at:at] = ["dump dmesh all mesh/stl 250 post/mesh*.stl"]
    return _run(tmp_path_factory.mktemp("drum"), scene, lines, "drum"), scene


@pytest.fixture(scope="module")
def hopper(tmp_path_factory):
    """200 particles filled (recorded from step 0) and settled for 0.1 s, 0.02 s more, then the
    lid removed at step 6000 and 0.08 s of discharge; the fill and the discharge are two dump
    files (and two mesh dumps: LIGGGHTS cannot unfix a mesh while a mesh dump is active)."""
    scene = make_hopper(num_particles=200, settle_time=0.1, t_open=0.02, duration=0.1)
    lines = render_input(scene, seed=1).splitlines()
    lines = [ln for ln in lines if not ln.startswith(("reset_timestep", "dump", "dump_modify"))]
    first_run = next(k for k, ln in enumerate(lines) if ln.startswith("run "))
    lines[first_run:first_run] = [
        f"dump dfill all custom 250 fill.dump {COLUMNS}",
        "dump mfill all mesh/stl 250 post/fill*.stl",
    ]
    at = lines.index("unfix walls")
    lines[at:at] = ["undump dfill", "undump mfill"]
    at = next(k for k, ln in enumerate(lines) if ln.startswith("fix walls") and k > at)
    lines[at + 1 : at + 1] = [
        f"dump ddis all custom 250 discharge.dump {COLUMNS}",
        "dump mdis all mesh/stl 250 post/discharge*.stl",
    ]
    return _run(tmp_path_factory.mktemp("hopper"), scene, lines, "hopper")


def test_the_drum_rotation_is_fitted_from_its_mesh_dumps(drum):
    work, scene = drum
    traj = trajectory_from_dumps(
        work / "traj.dump", [work / "drum.stl"], dem_dt=scene.dem_dt, mesh_dumps=[work / "post"]
    )
    (wall,) = traj.scene.walls
    m = wall.motion
    assert (m.kind, m.axis, m.origin, m.start_time, m.stop_time) == (
        "rotation",
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 0.0),
        0.0,
        None,
    )
    assert abs(m.omega - OMEGA) < 1e-6
    frames = read_mesh_dumps([work / "post"])
    assert len(frames) == 41
    worst = max(
        np.abs(wall.vertices_at(f.timestep * scene.dem_dt)[wall.faces] - f.triangles).max()
        for f in frames
    )
    assert worst < 1e-6
    assert traj.metadata["walls"][0]["motion_from"] == "mesh dumps"


def test_the_drum_script_and_its_mesh_dumps_agree_on_the_command_line(drum, tmp_path):
    work, scene = drum
    out = tmp_path / "drum.h5"
    argv = [str(work / "traj.dump"), "--input", str(work / "in.drum")]
    convert.main([*argv, "--mesh-dumps", str(work / "post"), "--kind", "drum", "--out", str(out)])
    traj = read_trajectory(out)
    (wall,) = traj.scene.walls
    assert wall.motion == scene.walls[0].motion  # the script's own numbers win
    assert (traj.scene.kind, traj.scene.name, traj.scene.dem_dt) == ("drum", "drum", 2e-5)
    assert traj.scene.materials == scene.materials


def _removal_case(hopper, **sources):
    dumps = [hopper / "fill.dump", hopper / "discharge.dump"]
    return trajectory_from_dumps(dumps, outflow_z=-0.01, kind="hopper", **sources)


@pytest.mark.parametrize(
    "sources",
    [
        pytest.param(lambda w: {"input_script": w / "in.hopper"}, id="script"),
        pytest.param(lambda w: {"log": w / "log.hopper"}, id="log"),
        pytest.param(
            lambda w: {
                "stl_files": [w / "hopper.stl", w / "lid.stl"],
                "dem_dt": 2e-5,
                "mesh_dumps": [w / "post"],
            },
            id="mesh_dumps",
        ),
    ],
)
def test_the_lid_is_removed_where_the_discharge_dump_starts(hopper, sources):
    traj = _removal_case(hopper, **sources(hopper))
    second = int(hopper.joinpath("discharge.dump").read_text().split("\n")[1])
    first = traj.metadata["first_timestep"]
    lid = traj.scene.wall("lid")
    assert second == 6000
    assert lid.removal_time == traj.times[(second - first) // 250]
    assert traj.scene.wall("hopper").removal_time is None


def test_hopper_particles_below_the_outflow_stay_gone(hopper):
    dumps = [hopper / "fill.dump", hopper / "discharge.dump"]
    traj = _removal_case(hopper, input_script=hopper / "in.hopper", mesh_dumps=[hopper / "post"])
    raw = frames_to_arrays(read_dumps(dumps), 2e-5)["positions"]  # as LIGGGHTS wrote them
    below = raw[..., 2] < -0.01  # LIGGGHTS keeps them down to the box floor at -0.03 m
    gone = np.logical_or.accumulate(below, axis=0)
    assert below.any(axis=0).sum() > 20  # many particles are still dumped below the outflow
    assert np.isnan(traj.positions[gone]).all() and np.isnan(traj.velocities[gone]).all()
    np.testing.assert_array_equal(traj.positions[~gone], raw[~gone])
    assert traj.metadata["left_through_outflow"] == gone[-1].sum()
    assert traj.num_frames == 41  # 25 fill frames + 17 discharge frames, step 6000 once
