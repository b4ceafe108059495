"""Rigid poses (Kabsch) and the one constant motion behind a sequence of them."""

from __future__ import annotations

import numpy as np
import pytest

from granular_pyg.dem_import.rigid_fit import (
    MotionFitError,
    Pose,
    dump_tolerance,
    fit_motion,
    fit_pose,
    pose_deviation,
)
from granular_pyg.scenes import WallMotion

DT = 2e-5
RNG = np.random.default_rng(3)
POINTS = RNG.uniform(-0.05, 0.05, (60, 3))


def _poses(motion: WallMotion, times) -> list[Pose]:
    return [Pose(*motion.pose(float(t))) for t in times]


def test_kabsch_recovers_a_pose_exactly():
    rot, shift = WallMotion("rotation", axis=(1, 2, 3), origin=(0.1, 0, 0), omega=1.0).pose(0.7)
    target = POINTS @ rot.T + shift
    pose = fit_pose(POINTS, target)
    assert pose_deviation(POINTS, target, pose) < 1e-15
    np.testing.assert_allclose(pose.rot, rot, atol=1e-14)


def test_kabsch_handles_a_planar_mesh_without_reflecting_it():
    flat = POINTS * [1, 1, 0]
    rot, shift = WallMotion("rotation", axis=(1, 0, 0), omega=1.0).pose(2.5)
    pose = fit_pose(flat, flat @ rot.T + shift)
    assert np.linalg.det(pose.rot) == pytest.approx(1.0)
    assert pose_deviation(flat, flat @ rot.T + shift, pose) < 1e-15


@pytest.mark.parametrize(
    "truth",
    [
        WallMotion("rotation", axis=(0, 1, 0), origin=(0.01, 0, 0.02), omega=-3.0),
        WallMotion("rotation", axis=(0, 0, 1), omega=2.0, start_time=0.02, stop_time=0.07),
        WallMotion("translation", velocity=(0.0, 0.1, -0.05), start_time=0.01),
        WallMotion("translation", velocity=(0.2, 0, 0), stop_time=0.05),
    ],
)
def test_a_constant_motion_is_recovered(truth):
    times = np.arange(0, 41) * 125 * DT  # 0 .. 0.1 s
    motion = fit_motion(times, _poses(truth, times), POINTS, 1e-9, DT)
    assert motion.kind == truth.kind
    for t in np.linspace(0, 0.1, 17):
        np.testing.assert_allclose(motion.pose(t)[0], truth.pose(t)[0], atol=1e-9)
        np.testing.assert_allclose(motion.pose(t)[1], truth.pose(t)[1], atol=1e-9)
    assert motion.start_time == pytest.approx(truth.start_time, abs=1e-12)
    assert (motion.stop_time is None) == (truth.stop_time is None)


def test_a_rotation_is_reported_with_a_positive_axis_and_signed_omega():
    truth = WallMotion("rotation", axis=(0, -1, 0), omega=2.0)
    times = np.arange(0, 21) * 250 * DT
    motion = fit_motion(times, _poses(truth, times), POINTS, 1e-9, DT)
    assert (motion.axis, motion.omega) == ((0.0, 1.0, 0.0), pytest.approx(-2.0, abs=1e-9))


def test_no_movement_is_static():
    times = np.arange(5) * 0.01
    assert fit_motion(times, [Pose(np.eye(3), np.zeros(3))] * 5, POINTS, 1e-6).kind == "static"


def test_a_motion_that_stops_and_restarts_is_refused():
    times = np.arange(0, 9) * 0.01
    shifts = [0, 1, 2, 2, 2, 3, 4, 5, 6]
    poses = [Pose(np.eye(3), np.array([0.0, 0.0, 0.001 * s])) for s in shifts]
    with pytest.raises(MotionFitError, match="stops and restarts"):
        fit_motion(times, poses, POINTS, 1e-7)


def test_an_accelerating_motion_is_refused():
    times = np.arange(0, 9) * 0.01
    poses = [Pose(np.eye(3), np.array([0.0, 0.0, 5.0 * t * t])) for t in times]
    with pytest.raises(MotionFitError, match="no constant translation"):
        fit_motion(times, poses, POINTS, 1e-7)


def test_tolerance_counts_the_dump_rounding():
    assert dump_tolerance(np.array([[0.05, 0, 0]])) == pytest.approx(1e-6 + 6e-6 * 0.05)
