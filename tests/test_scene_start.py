"""A rollout from the scene alone: packed particles at rest at the start of the fill, and
`python -m granular_pyg.rollout ckpt=... scene=hopper` with no trajectory."""

from __future__ import annotations

import numpy as np
import pytest

from granular_pyg.config import compose
from granular_pyg.scene_start import scene_start, whole_job_steps
from granular_pyg.scenes import make_hopper


def test_the_start_is_a_packing_at_rest_at_the_start_of_the_fill():
    scene = make_hopper(num_particles=300, settle_time=0.6, frame_dt=0.0025)
    start = scene_start(scene, history=5, frames_per_step=8, seed=4)
    assert start.positions.shape == (41, 300, 3) and start.scene is scene
    assert start.times[0] == pytest.approx(-0.6) and start.frame_dt == pytest.approx(0.0025)
    assert (start.velocities == 0).all()
    assert (start.positions == start.positions[0]).all()  # at rest: every history frame alike
    pos, r = start.positions[0].astype(np.float64), start.radii.astype(np.float64)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos))
    assert (d >= r[:, None] + r[None] - 1e-6).all()  # float32 positions
    assert start.metadata["start"] == "scene"


def test_a_bed_too_large_for_its_region_fills_the_walls_interior_below_the_box_top():
    # The region (a box inside the V at its lowest point) would have to rise above the
    # simulation box to hold 2,000 particles at the packing's fraction: the walls' interior
    # takes them instead, every particle whole inside the walls and the box, none overlapping.
    from scipy.spatial import ConvexHull

    from granular_pyg.inference import outside_scene
    from granular_pyg.scenes.containment import walls_at

    scene = make_hopper(num_particles=2000)
    start = scene_start(scene, history=1, frames_per_step=1, seed=1)
    pos, r = start.positions[0].astype(np.float64), start.radii.astype(np.float64)
    assert not outside_scene(start, 0).any()
    assert (pos[:, 2] + r <= scene.domain_hi[2] + 1e-6).all()
    hull = ConvexHull(walls_at(scene, float(start.times[0]))[0].reshape(-1, 3))
    signed = pos @ hull.equations[:, :3].T + hull.equations[:, 3]
    assert (signed <= -r[:, None] + 1e-6).all()  # whole particles inside the walls
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos))
    assert (d >= r[:, None] + r[None] - 1e-6).all()
    # Wider than the scene's own region: it did not fit there.
    assert np.ptp(pos[:, 0]) > scene.particles.fill_hi[0] - scene.particles.fill_lo[0]


def test_the_whole_job_spans_fill_settle_and_the_recorded_time():
    scene = make_hopper(settle_time=0.6, duration=1.0, frame_dt=0.0025)
    # 1.6 s in learned steps of 8 x 2.5 ms = 20 ms: 80, less the 5 of the history.
    assert whole_job_steps(scene, history=5, frames_per_step=8) == 75


def test_rollout_starts_from_the_scene_without_a_trajectory(tmp_path):
    from granular_pyg.rollout import rollout

    cfg = compose(
        "rollout",
        [
            "ckpt=pretrained:hopper",
            "scene=hopper",
            "scene.build.num_particles=300",
            "steps=3",
            "threads=1",
            "progress=false",
            f"out={tmp_path / 'from_scene.h5'}",
        ],
    )
    pred, out = rollout(cfg)
    assert out.is_file() and pred.num_particles == 300
    assert pred.metadata["steps"] == 3
    assert pred.times[0] == pytest.approx(-cfg.scene.build.settle_time)
    assert np.isfinite(pred.positions[-1]).all()
