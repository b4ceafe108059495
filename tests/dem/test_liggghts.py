"""Rendering LIGGGHTS input from a Scene, and the errors users see before and from LIGGGHTS."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from granular_pyg.dem.liggghts import (
    INSTALL_HINT,
    LiggghtsError,
    _is_prime,
    check_wall_for_liggghts,
    find_liggghts,
    prime_seeds,
    render_input,
    run_liggghts,
    write_ascii_stl,
)
from granular_pyg.errors import InputError
from granular_pyg.scenes import Materials, Wall, make_drum, make_hopper


def _runs(script: str) -> list[int]:
    return [int(line.split()[1]) for line in script.splitlines() if line.startswith("run ")]


def test_hopper_script_removes_the_lid_at_t_open_and_records_every_frame():
    scene = make_hopper(duration=1.0, t_open=0.05, frame_dt=0.0025, dem_dt=2e-5, settle_time=0.6)
    script = render_input(scene, seed=3)
    lines = script.splitlines()
    assert _runs(script) == [30000, 2500, 47500]  # settle, until t_open, the rest
    lid_gone = lines.index("unfix wall_lid")
    assert lines[lid_gone - 1] == "unfix walls"
    assert lines[lid_gone + 1].endswith("n_meshes 1 meshes wall_hopper")
    assert "meshes wall_hopper wall_lid" in script  # both walls before t_open
    assert "dump dmp all custom 125 traj.dump id type x y z vx vy vz radius" in script
    assert script.index("reset_timestep 0") < script.index("dump dmp")
    assert "nparticles 2000" in script


def test_drum_script_rotates_the_mesh_with_the_right_period_from_the_first_frame():
    scene = make_drum(omega=2.0)
    script = render_input(scene, seed=3)
    move = next(line for line in script.splitlines() if "move/mesh" in line)
    assert "mesh wall_drum rotate origin 0.0 0.0 0.0 axis 0.0 1.0 0.0" in move
    assert float(move.split("period")[1]) == pytest.approx(math.pi)
    assert script.index('print "GPYG_PHASE record"') < script.index(move)
    # Negative omega turns the axis round instead.
    flipped = render_input(make_drum(omega=-2.0), seed=3)
    assert "axis -0.0 -1.0 -0.0" in flipped


def test_rolling_friction_switches_the_contact_model():
    scene = make_hopper(materials=Materials(rolling_friction=0.1))
    script = render_input(scene, seed=1)
    assert "pair_style gran model hertz tangential history rolling_friction cdt" in script
    assert "coefficientRollingFriction peratomtypepair 1 0.1" in script


def test_seeds_are_distinct_primes_above_10000_and_reproducible():
    seeds = prime_seeds(42)
    assert len(set(seeds)) == 3
    assert all(s > 10000 and _is_prime(s) for s in seeds)
    assert prime_seeds(42) == seeds != prime_seeds(43)


def test_stl_files_are_ascii(tmp_path):
    wall = make_hopper().wall("lid")
    write_ascii_stl(wall, tmp_path / "lid.stl")
    text = (tmp_path / "lid.stl").read_text()
    assert text.startswith("solid")
    assert text.count("facet normal") == len(wall.faces)


def test_sliver_triangle_is_rejected_before_liggghts_starts(tmp_path):
    sliver = Wall("bad_wall", np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-4, 0]]), [[0, 1, 2]])
    with pytest.raises(InputError, match=r"wall bad_wall: 1 triangle\(s\) have an angle"):
        check_wall_for_liggghts(sliver)
    scene = make_hopper()
    scene.walls.append(sliver)
    with pytest.raises(InputError, match="bad_wall"):
        run_liggghts(scene, tmp_path, seed=1, progress=False)
    assert not (tmp_path / "in.liggghts").exists()


def test_wall_outside_the_box_is_rejected(tmp_path):
    scene = make_drum()
    scene.domain_hi = (0.01, 0.1, 0.1)
    with pytest.raises(InputError, match="leaves the simulation box"):
        run_liggghts(scene, tmp_path, seed=1, progress=False)


def test_missing_liggghts_names_the_install_command():
    with pytest.raises(InputError, match="apt-get install -y --no-install-recommends liggghts"):
        find_liggghts("liggghts-not-installed-here")
    assert "liggghts" in INSTALL_HINT


def _tiny_hopper(**kwargs):
    defaults = dict(num_particles=150, duration=0.02, t_open=0.01, settle_time=0.1, frame_dt=0.005)
    return make_hopper(**(defaults | kwargs))


@pytest.mark.slow
def test_liggghts_error_text_is_shown(tmp_path):
    scene = _tiny_hopper(materials=Materials(restitution=1.5))
    with pytest.raises(LiggghtsError, match=r"coefficientRestitution <= 1 required"):
        run_liggghts(scene, tmp_path, seed=1, progress=False)


@pytest.mark.slow
def test_short_fill_stops_with_the_inserted_count(tmp_path):
    scene = _tiny_hopper()
    scene.particles = dataclasses.replace(scene.particles, count=5000)
    with pytest.raises(InputError, match=r"LIGGGHTS inserted \d+ of 5000 particles"):
        run_liggghts(scene, tmp_path, seed=1, progress=False)
