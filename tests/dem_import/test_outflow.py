"""Particles leaving an imported run: the rollout's outflow rule, late insertion, and
particles that would come back."""

from __future__ import annotations

import numpy as np
import pytest

from granular_pyg.dem_import.convert import trajectory_from_dumps
from granular_pyg.errors import InputError
from tests.dem.dump_text import frame_text, write_dump

DT = 2e-5


def _frames(z_by_frame, insert_at=None, skip=None):
    """Two particles falling straight down by ``z_by_frame`` (rows: frames, cols: particles);
    particle 2 enters at frame ``insert_at``; ``skip = (frame, id)`` leaves one atom out."""
    out = []
    for k, zs in enumerate(z_by_frame):
        ids = [i for i in (1, 2) if not (i == 2 and insert_at is not None and k < insert_at)]
        ids = [i for i in ids if (k, i) != skip]
        pos = np.array([[0.01 * i, 0.0, zs[i - 1]] for i in ids])
        vel = np.zeros_like(pos)
        out.append((k * 100, ids, pos, vel))
    return out


def _write(tmp_path, frames):
    path = tmp_path / "dump.liggghts"
    path.write_text("".join(frame_text(s, i, p, v) for s, i, p, v in frames))
    return path


def test_a_particle_below_outflow_is_gone_for_good_even_if_still_dumped(tmp_path):
    # Particle 1 drops below -0.01 at frame 2, sits in a catch box, and even bounces back.
    z = [[0.02, 0.05], [0.0, 0.05], [-0.02, 0.05], [-0.015, 0.05], [0.001, 0.05]]
    traj = trajectory_from_dumps(_write(tmp_path, _frames(z)), dem_dt=DT, outflow_z=-0.01)
    present = np.isfinite(traj.positions[..., 0])
    assert present[:, 0].tolist() == [True, True, False, False, False]
    assert present[:, 1].all()
    assert np.isnan(traj.velocities[2:, 0]).all()
    assert traj.metadata["left_through_outflow"] == 1


def test_a_particle_inserted_later_is_kept(tmp_path):
    z = [[0.02, 0.05]] * 4
    traj = trajectory_from_dumps(_write(tmp_path, _frames(z, insert_at=2)), dem_dt=DT)
    assert np.isfinite(traj.positions[:, 1, 0]).tolist() == [False, False, True, True]


def test_a_particle_missing_from_a_middle_frame_is_refused_naming_it(tmp_path):
    z = [[0.02, 0.05]] * 5
    dump = _write(tmp_path, _frames(z, skip=(2, 2)))
    with pytest.raises(
        InputError,
        match=r"particle id 2 is missing from TIMESTEP 200 \(frame 2\) but back at "
        r"TIMESTEP 300 \(frame 3\)",
    ):
        trajectory_from_dumps(dump, dem_dt=DT)


def test_a_particle_below_outflow_from_the_start_is_left_out(tmp_path):
    z = [[-0.02, 0.05]] * 3
    traj = trajectory_from_dumps(_write(tmp_path, _frames(z)), dem_dt=DT, outflow_z=-0.01)
    assert (traj.ids.tolist(), traj.metadata["never_present"]) == ([2], 1)


def test_outflow_from_walls_yaml_sets_the_scene_floor(tmp_path):
    walls = tmp_path / "walls.yaml"
    walls.write_text("kind: hopper\noutflow_z: -0.01\n")
    dump = write_dump(tmp_path / "d.dump", _frames([[0.02, 0.05], [-0.02, 0.05]]))
    scene = trajectory_from_dumps(dump, dem_dt=DT, walls=walls).scene
    assert (scene.outflow_z, scene.domain_lo[2], scene.kind, scene.name) == (
        -0.01,
        -0.01,
        "hopper",
        "hopper",
    )
