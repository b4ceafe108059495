"""Reading a run's LIGGGHTS input script or log: materials, gravity, time step, meshes, motions,
removals; round trip through the scripts this project renders."""

from __future__ import annotations

import dataclasses
import math
import subprocess

import numpy as np
import pytest

from granular_pyg.dem.liggghts import find_liggghts, render_input, write_ascii_stl
from granular_pyg.dem_import.convert import trajectory_from_dumps
from granular_pyg.dem_import.liggghts_input import read_run_script
from granular_pyg.dem_import.mesh_dump import read_mesh_dumps
from granular_pyg.errors import InputError
from granular_pyg.scenes import Materials, make_drum, make_hopper
from tests.dem.dump_text import falling, plate, write_dump, write_stl

MATERIALS = Materials(
    youngs_modulus=7.5e6,
    poisson_ratio=0.28,
    restitution=0.55,
    friction=0.45,
    rolling_friction=0.02,
    density=2650.0,
)


def _render(tmp_path, scene):
    for wall in scene.walls:
        write_ascii_stl(wall, tmp_path / f"{wall.name}.stl")
    script = tmp_path / f"in.{scene.name}"
    script.write_text(render_input(scene, seed=3))
    return script


@pytest.mark.parametrize("build", [make_hopper, make_drum])
def test_a_rendered_script_reads_back_into_its_scene(tmp_path, build):
    scene = build(materials=MATERIALS)
    scene.gravity = (0.5, 0.0, -9.7)
    script = _render(tmp_path, scene)
    # Recorded frames start at TIMESTEP 0 (the script resets the step after settling).
    steps = range(0, round(0.05 / scene.dem_dt) + 1, 125)
    dump = write_dump(tmp_path / "traj.dump", falling(steps, dem_dt=scene.dem_dt))
    traj = trajectory_from_dumps(dump, input_script=script)
    got = traj.scene
    assert got.materials == MATERIALS
    np.testing.assert_allclose(got.gravity, scene.gravity, rtol=1e-15, atol=1e-15)
    assert got.dem_dt == scene.dem_dt
    for want, wall in zip(scene.walls, got.walls, strict=True):
        assert wall.name == want.name
        np.testing.assert_allclose(wall.vertices[wall.faces], want.triangles, atol=1e-12)
        assert wall.motion == want.motion
        assert wall.removal_time == pytest.approx(want.removal_time, abs=1e-12)
    line = int(traj.metadata["sources"]["dem_dt"].rsplit(":", 1)[1])
    assert script.read_text().splitlines()[line - 1] == f"timestep {scene.dem_dt!r}"


def test_a_drum_turned_back_and_forth_reads_back_as_one_reversing_rotation(tmp_path):
    scene = make_drum(spin_start=0.1, spin_reverse=0.6, spin_stop=1.5, omega=-2.5)
    script = _render(tmp_path, scene)
    assert script.read_text().count("fix move_drum all move/mesh") == 2
    motion, where = read_run_script(script).motion_for("wall_drum", scene.dem_dt)
    want = scene.walls[0].motion
    times = (motion.start_time, motion.stop_time, *motion.reverse_times)
    assert times == pytest.approx((0.1, 1.5, 0.6), abs=1e-12)
    first = script.read_text().splitlines()[int(where.rsplit(":", 1)[1]) - 1]
    assert first.startswith("fix move_drum") and "axis -0.0 -1.0 -0.0" in first
    for t in np.linspace(0.0, 2.0, 41):  # the same poses (the axis may come back flipped)
        np.testing.assert_allclose(motion.pose(t)[0], want.pose(t)[0], atol=1e-9)
    # Two fixes that do not turn one rotation back at the same speed stay refused.
    text = script.read_text().replace("period 2.5132741228718345\n", "period 2.0\n", 1)
    (tmp_path / "other.run").write_text(text)
    with pytest.raises(InputError, match=r"2 move/mesh fixes .*turning back at the same speed"):
        read_run_script(tmp_path / "other.run").motion_for("wall_drum", scene.dem_dt)


def test_a_log_reads_like_its_script_and_skips_unsubstituted_lines(tmp_path):
    log = tmp_path / "log.liggghts"
    log.write_text(
        "LIGGGHTS (Version LIGGGHTS-PUBLIC 3.8.0)\n"
        "variable dt equal 1e-5\n"
        "timestep ${dt}\n"
        "timestep 1e-05\n"
        "fix wall_lid all mesh/surface file lid.stl type 1\n"
        "fix walls all wall/gran model hertz tangential history mesh n_meshes 1 meshes wall_lid\n"
        "run 1000\n"
        "Setting up run ...\n"
        "    Step    Atoms         KinEng \n"
        "       0        0              0 \n"
        "     500       10              0 \n"
        "unfix wall_lid\n"
    )
    script = read_run_script(log, is_log=True)
    assert script.timestep == (1e-5, f"{log}:4")
    assert script.meshes["wall_lid"].removed_step == 1000


def test_a_log_after_read_restart_counts_steps_from_its_thermo_table(tmp_path):
    log = tmp_path / "log.liggghts"
    log.write_text(
        "read_restart fill.restart\n"
        "fix wall_lid all mesh/surface file lid.stl type 1\n"
        "run 400\n"
        "    Step    Atoms         KinEng \n"
        "   80000      10              0 \n"
        "unfix wall_lid\n"
    )
    assert read_run_script(log, is_log=True).meshes["wall_lid"].removed_step == 80400


def test_script_variables_with_one_value_are_substituted(tmp_path):
    script = tmp_path / "in.run"
    script.write_text(
        "variable dt equal 2.5e-5\nvariable w index 3.0\ntimestep ${dt}\n"
        "fix g all gravity $w vector 0 0 -1 # comment\n"
    )
    read = read_run_script(script)
    assert (read.timestep[0], read.gravity[0]) == (2.5e-5, (0.0, 0.0, -3.0))


def test_an_unreadable_variable_is_refused_naming_it_and_the_line(tmp_path):
    script = tmp_path / "in.run"
    script.write_text("variable dt equal 1e-5*2\ntimestep ${dt}\n")
    read = read_run_script(script)  # refused only when the value is needed
    with pytest.raises(InputError, match=r"in.run:2: \$\{dt\} is a variable .*--log"):
        read.timestep  # noqa: B018


def test_an_unreadable_value_given_elsewhere_does_not_matter(tmp_path):
    script = tmp_path / "in.run"
    script.write_text(
        "timestep ${dt}\nfix m1 all property/global youngsModulus peratomtype ${E}\n"
        "fix m2 all property/global poissonsRatio peratomtype 0.25\n"
    )
    walls = tmp_path / "walls.yaml"
    walls.write_text("materials: {youngs_modulus: 1.0e+7}\n")
    dump = write_dump(tmp_path / "d.dump", falling(range(0, 1000, 125)))
    traj = trajectory_from_dumps(dump, dem_dt=2e-5, input_script=script, walls=walls)
    assert (traj.scene.materials.youngs_modulus, traj.scene.materials.poisson_ratio) == (1e7, 0.25)
    with pytest.raises(InputError, match=r"in.run:2: \$\{E\} is a variable"):
        trajectory_from_dumps(dump, dem_dt=2e-5, input_script=script)


def test_a_removal_after_read_restart_in_a_script_needs_the_log(tmp_path):
    write_stl(tmp_path / "lid.stl", plate(z=0.0))
    script = tmp_path / "in.run"
    script.write_text(
        "timestep 2e-5\nread_restart fill.restart\n"
        "fix wall_lid all mesh/surface file lid.stl type 1\nrun 400\nunfix wall_lid\n"
    )
    dump = write_dump(tmp_path / "d.dump", falling(range(0, 1000, 125)))
    with pytest.raises(InputError, match=r"in.run:5: the step of 'unfix wall_lid' .*read_restart"):
        trajectory_from_dumps(dump, input_script=script)


def test_an_unsupported_motion_is_refused_when_it_is_needed(tmp_path):
    script = tmp_path / "in.run"
    script.write_text(
        "fix cad all mesh/surface file cad.stl type 1\n"
        "fix mv all move/mesh mesh cad rotate/variable origin 0 0 0 axis 0 0 1 omega v_w\n"
    )
    read = read_run_script(script)
    with pytest.raises(InputError, match=r"in.run:2: move/mesh style 'rotate/variable'.*walls"):
        read.motion_for("cad", 1e-5)


def test_motions_start_and_stop_at_their_steps(tmp_path):
    script = tmp_path / "in.run"
    script.write_text(
        "timestep 1e-5\nfix cad all mesh/surface file cad.stl type 1\nrun 100\n"
        "fix mv all move/mesh mesh cad linear 0 0 0.1\nrun 300\nunfix mv\nrun 50\n"
        "reset_timestep 0\nrun 10 upto\n"
    )
    motion, where = read_run_script(script).motion_for("cad", 1e-5)
    assert (motion.kind, motion.velocity, where.endswith(":4")) == (
        "translation",
        (0, 0, 0.1),
        True,
    )
    assert (motion.start_time, motion.stop_time) == (pytest.approx(1e-3), pytest.approx(4e-3))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("units lj\n", "only LIGGGHTS runs in SI units"),
        ("timestep 1e-5\nrun 10\ntimestep 2e-5\n", "the time step changes"),
        ("label loop\njump SELF loop\n", "loops and conditions"),
    ],
)
def test_scripts_this_reader_cannot_follow_are_refused(tmp_path, text, message):
    script = tmp_path / "in.run"
    script.write_text(text)
    with pytest.raises(InputError, match=message):
        read_run_script(script).timestep  # noqa: B018


def test_include_is_followed(tmp_path):
    (tmp_path / "materials.in").write_text(
        "fix m1 all property/global youngsModulus peratomtype 1e7\n"
    )
    script = tmp_path / "in.run"
    script.write_text("include materials.in\n")
    assert read_run_script(script).materials({1})["youngs_modulus"][0] == 1e7


def test_materials_are_read_for_the_particles_atom_type(tmp_path):
    script = tmp_path / "in.run"
    script.write_text(
        "fix m1 all property/global youngsModulus peratomtype 1e7 5e6\n"
        "fix m3 all property/global coefficientRestitution peratomtypepair 2 0.9 0.8 0.8 0.5\n"
        "fix pts all particletemplate/sphere 15485863 atom_type 2 density constant 1000 "
        "radius constant 0.002\n"
    )
    read = read_run_script(script)
    got = {k: v for k, (v, _) in read.materials(read.particle_types()).items()}
    assert got == {"youngs_modulus": 5e6, "restitution": 0.5, "density": 1000.0}
    with pytest.raises(InputError, match=r"youngsModulus differs between .* \[1, 2\]"):
        read.materials({1, 2})


def test_different_template_densities_need_walls_yaml(tmp_path):
    script = tmp_path / "in.run"
    script.write_text(
        "timestep 2e-5\n"
        "fix a all particletemplate/sphere 1 atom_type 1 density constant 1000 radius constant 1\n"
        "fix b all particletemplate/sphere 2 atom_type 1 density constant 3000 radius constant 2\n"
    )
    dump = write_dump(tmp_path / "d.dump", falling(range(0, 1000, 125)))
    with pytest.raises(InputError, match=r"no single density \(1000 .*3000 .*materials.density"):
        trajectory_from_dumps(dump, input_script=script)
    walls = tmp_path / "walls.yaml"
    walls.write_text("materials:\n  density: 2000\n")
    traj = trajectory_from_dumps(dump, input_script=script, walls=walls)
    assert traj.scene.materials.density == 2000.0


def test_a_command_line_value_that_disagrees_with_the_script_is_refused(tmp_path):
    script = tmp_path / "in.run"
    script.write_text("timestep 2e-5\n")
    dump = write_dump(tmp_path / "d.dump", falling(range(0, 1000, 125)))
    with pytest.raises(InputError, match=r"time step: 1e-05 from --dem-dt disagrees .*in.run:1"):
        trajectory_from_dumps(dump, dem_dt=1e-5, input_script=script)
    # The same value twice is fine.
    assert trajectory_from_dumps(dump, dem_dt=2e-5, input_script=script).scene.dem_dt == 2e-5


def test_mesh_load_transforms_match_liggghts(tmp_path):
    """``scale``, ``move`` and ``rotate`` in ``fix mesh/surface`` are applied in the order
    given, about the origin, as LIGGGHTS 3.8.0 does (compared with its own mesh dump)."""
    write_stl(tmp_path / "b.stl", plate(z=0.02, half=0.01))
    (tmp_path / "in.run").write_text(
        "atom_style granular\natom_modify map array sort 0 0.0\nboundary f f f\nnewton off\n"
        "communicate single vel yes\nunits si\n"
        "region domain block -0.1 0.1 -0.1 0.1 -0.1 0.1 units box\ncreate_box 1 domain\n"
        "fix m1 all property/global youngsModulus peratomtype 5e6\n"
        "fix m2 all property/global poissonsRatio peratomtype 0.3\n"
        "fix m3 all property/global coefficientRestitution peratomtypepair 1 0.6\n"
        "fix m4 all property/global coefficientFriction peratomtypepair 1 0.5\n"
        "pair_style gran model hertz tangential history\npair_coeff * *\ntimestep 1e-5\n"
        "fix wb all mesh/surface file b.stl type 1 scale 2 move 0.01 0 0.005 "
        "rotate axis 1 1 0 angle 30\n"
        "fix walls all wall/gran model hertz tangential history mesh n_meshes 1 meshes wb\n"
        "dump d all mesh/stl 10 m*.stl\nrun 0\n"
    )
    subprocess.run(
        [find_liggghts(), "-in", "in.run"], cwd=tmp_path, check=True, capture_output=True
    )
    mesh = read_run_script(tmp_path / "in.run").meshes["wb"]
    (frame,) = read_mesh_dumps([tmp_path / "m0.stl"])
    got = mesh.transform(plate(z=0.02, half=0.01).triangles.reshape(-1, 3))
    np.testing.assert_allclose(got.reshape(-1, 3, 3), frame.triangles, atol=1e-7)
    assert math.isclose(np.abs(got).max(), np.abs(frame.triangles).max(), rel_tol=1e-5)


def test_scene_materials_defaults_fill_what_the_script_leaves_out(tmp_path):
    script = tmp_path / "in.run"
    script.write_text("timestep 2e-5\nfix m2 all property/global poissonsRatio peratomtype 0.2\n")
    dump = write_dump(tmp_path / "d.dump", falling(range(0, 1000, 125)))
    traj = trajectory_from_dumps(dump, input_script=script)
    assert traj.scene.materials == dataclasses.replace(Materials(), poisson_ratio=0.2)
    assert traj.metadata["sources"]["materials.density"] == "default"
