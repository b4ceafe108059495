"""The neighbours suite's hopper at rest: a real LIGGGHTS bed that does not move."""

from __future__ import annotations

import numpy as np

from granular_pyg.bench.neighbours import resting_hopper


def test_resting_hopper_is_a_settled_bed_behind_its_lid():
    traj = resting_hopper(num_particles=400, steps=3, step_s=0.02)
    assert traj.num_frames == 5 and np.allclose(np.diff(traj.times), 0.02)
    assert traj.scene.params["t_open"] > traj.times[-2]  # closed for every replayed step
    before_open = traj.positions[traj.times < traj.scene.params["t_open"]]
    assert np.isfinite(before_open).all()
    moves = np.linalg.norm(np.diff(before_open, axis=0), axis=-1)
    assert moves.max() < 2.5e-4  # under half the smallest skin (0.5 mm) per 20 ms step
