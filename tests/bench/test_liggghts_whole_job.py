"""The `liggghts` suite's whole job: LIGGGHTS's fill + settle + recorded runs against the
learned rollout from the scene alone, for the user's own scene file, scaled by particle count."""

from __future__ import annotations

import math

import pytest

from granular_pyg.bench.liggghts import loop_times, run, scaled_build
from granular_pyg.errors import InputError

TINY = """name: tiny_hopper
build:
  _target_: granular_pyg.scenes.make_hopper
  alpha_deg: 60.0
  opening: 0.012
  depth: 0.009
  height: 0.05
  num_particles: 150
  particle_radius: 0.0015
  t_open: 0.04
  duration: 0.3
  frame_dt: 0.0025
  dem_dt: 2.0e-5
  settle_time: 0.3
  outflow_depth: 0.02
"""


def test_loop_times_split_the_recorded_phase_from_the_whole_job(tmp_path):
    log = tmp_path / "log.liggghts"
    log.write_text(
        "Loop time of 4.5 on 1 procs for 30000 steps with 150 atoms\n"
        "x\nLoop time of 1.25 on 1 procs for 2000 steps with 150 atoms\n"
        "Loop time of 0.75 on 1 procs for 13000 steps with 120 atoms\n"
    )
    assert loop_times(log) == (2.0, 6.5)


def test_scenes_scale_to_a_particle_count():
    hopper = {"_target_": "granular_pyg.scenes.make_hopper", "depth": 0.03, "num_particles": 2000}
    scaled = scaled_build(hopper, 20000)
    assert scaled == hopper | {"depth": pytest.approx(0.3), "num_particles": 20000}
    mesh = {"_target_": "granular_pyg.scenes.make_mesh_scene", "scale": 1.0, "num_particles": 1000}
    assert scaled_build(mesh, 8000)["scale"] == pytest.approx(2.0)
    assert scaled_build(mesh, None) is mesh
    with pytest.raises(InputError, match="no rule to scale"):
        scaled_build({"_target_": "x.make_other", "num_particles": 5}, 10)


@pytest.mark.slow
def test_the_whole_job_of_a_users_scene_file(tmp_path):
    path = tmp_path / "tiny_hopper.yaml"
    path.write_text(TINY)
    result = run("pretrained:hopper", scene=str(path), mpi_procs=(1,), threads=1, wall_guard=False)
    liggghts, learned = result.rows
    assert liggghts["whole_job_s"] > liggghts["wall_s"] > 0  # fill + settle cost too
    assert liggghts["whole_job_simulated_s"] == pytest.approx(0.6)
    assert learned["whole_job_wall_s"] > 0
    assert learned["whole_job_simulated_s"] == pytest.approx(0.6 - 5 * 0.02)  # less the history
    r = result.results
    assert math.isclose(
        r["learned_whole_job_speedup_over_serial"],
        liggghts["whole_job_s"] / learned["whole_job_wall_s"],
    )
    assert 0 <= learned["whole_job_discharged_fraction_pred"] <= 1
    names = [t.name for t in result.targets]
    assert "learned whole job (from the scene alone) / serial LIGGGHTS's whole job" in names
    assert "tiny_hopper" in result.notes or "scene" in result.notes
