"""Pareto suite helpers: the front, and EMD taken at fixed simulated horizons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from granular_pyg.bench.pareto import emd_at_horizons, pareto_front
from granular_pyg.io import Trajectory


def test_front_of_four_settings():
    # (wall s per simulated s, error): b is dominated by a, d by c; c beats a on error.
    speed = [1.0, 2.0, 4.0, 5.0]
    error = [0.3, 0.4, 0.1, 0.1]
    assert pareto_front(speed, error) == [True, False, True, False]


def test_ties_stay_on_the_front_and_nan_never_does():
    assert pareto_front([1.0, 1.0, 2.0], [0.5, 0.5, math.nan]) == [True, True, False]


def test_front_matches_brute_force_on_random_points():
    rng = np.random.default_rng(0)
    speed, error = rng.random(40).tolist(), rng.random(40).tolist()
    on = pareto_front(speed, error)
    for i in range(40):
        better = [
            j
            for j in range(40)
            if speed[j] <= speed[i]
            and error[j] <= error[i]
            and (speed[j], error[j]) != (speed[i], error[i])
        ]
        assert on[i] == (not better)


def _trajectory(times: np.ndarray, positions: np.ndarray, initial: int = 1) -> Trajectory:
    n = positions.shape[1]
    return Trajectory(
        positions=positions.astype(np.float32),
        velocities=np.zeros_like(positions, dtype=np.float32),
        times=times,
        radii=np.full(n, 0.0015, dtype=np.float32),
        ids=np.arange(1, n + 1),
        metadata={"initial_frames": initial},
    )


def test_emd_at_horizons_compares_frames_at_the_same_simulated_time():
    # Truth every 10 ms; a k = 5 rollout every 50 ms, off by 1 mm in x from its second frame on.
    times = np.arange(0.0, 0.31, 0.01)
    truth_pos = np.zeros((len(times), 2, 3))
    truth_pos[:, 1, 0] = 0.01
    truth = _trajectory(times, truth_pos)
    pred_times = times[::5]
    pred_pos = truth_pos[::5].copy()
    pred_pos[1:, :, 0] += 0.001
    pred = _trajectory(pred_times, pred_pos, initial=1)
    got = emd_at_horizons(truth, pred, (0.05, 0.1, 0.2, 0.5))
    assert set(got) == {0.05, 0.1, 0.2}  # 0.5 s is past the rollout
    for value in got.values():
        assert value == pytest.approx(1e-6, rel=1e-4)  # W2^2 of a 1 mm shift, m^2


def test_a_setting_is_named_by_its_run_folder_or_pretrained_name():
    from granular_pyg.bench.pareto import _label

    config = {"model": {"processor": {"layer": "attention"}, "latent": 32, "radius": 0.005}}
    run = _label("outputs/pareto/latent32/checkpoints/last.ckpt", config, 8)
    assert run == "pareto/latent32: attention, latent 32, R 5 mm, k 8"
    assert _label("pretrained:hopper", config, 4).startswith("pretrained/hopper: attention")


def test_its_defaults_are_checkpoints_and_trajectories_a_fresh_checkout_has():
    from granular_pyg.config import compose
    from granular_pyg.pretrained import resolve_checkpoint

    run = compose("bench", ["suite=pareto"]).suite.run
    assert run.trajectories is None  # the bundled sample's test trajectories
    assert len(run.ckpts) >= 2
    for ckpt in run.ckpts:
        assert str(ckpt).startswith("pretrained:")
        assert resolve_checkpoint(ckpt).is_file()
