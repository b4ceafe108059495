"""Metrics: tiny exact cases and property tests against brute-force references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from granular_pyg.errors import InputError
from granular_pyg.metrics import (
    centre_of_mass_swing,
    crushed_particles,
    discharge_rate,
    dynamic_angle_of_repose,
    emd,
    emd_at_powers,
    flow_profile,
    mixing_classes,
    mixing_entropy,
    mixing_entropy_curve,
    outlet_point,
    position_mse,
)
from granular_pyg.scenes import make_drum, make_hopper

# --- EMD ------------------------------------------------------------------------------------


def test_emd_of_a_set_with_itself_is_zero():
    pts = np.random.default_rng(0).normal(size=(50, 3))
    assert emd(pts, pts) == pytest.approx(0.0, abs=1e-15)
    assert emd(pts, pts[::-1], squared=False) == pytest.approx(0.0, abs=1e-12)


def test_emd_of_a_shift_is_the_squared_shift():
    pts = np.random.default_rng(1).normal(size=(30, 3))
    shift = np.array([0.3, 0.0, 0.4])
    assert emd(pts, pts + shift) == pytest.approx(0.25, rel=1e-9)  # |shift|^2
    assert emd(pts, pts + shift, squared=False) == pytest.approx(0.5, rel=1e-9)


def test_emd_of_large_sets_is_that_of_the_same_random_particles_of_both():
    rng = np.random.default_rng(2)
    truth = rng.normal(size=(60, 3))
    pred = truth + rng.normal(scale=0.01, size=(60, 3))
    subset = emd(truth, pred, max_points=20)
    assert subset == emd(truth, pred, max_points=20)  # a fixed draw
    assert emd(truth, truth, max_points=20) == pytest.approx(0.0, abs=1e-15)  # paired rows
    assert emd(truth, pred + np.array([0.3, 0, 0.4]), max_points=20) == pytest.approx(
        subset + 0.25, abs=0.02
    )
    exact = emd(truth, pred, max_points=None)
    assert subset == pytest.approx(exact, rel=0.5)  # the same scale as all 60 particles
    left = pred.copy()
    left[::2] = np.nan  # particles that left the prediction are dropped after the draw
    assert np.isfinite(emd(truth, left, max_points=20))
    broken = truth.copy()
    broken[59, 1] = np.nan  # a corrupted row is refused even when it is not drawn
    with pytest.raises(InputError, match="only some coordinates"):
        emd(broken, pred, max_points=20)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 9), seed=st.integers(0, 10**6))
def test_emd_matches_brute_force_assignment(n, seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    # Equal sizes and uniform weights: the optimal plan is a permutation.
    for squared in (True, False):
        cost = ((a[:, None] - b[None]) ** 2).sum(-1)
        cost = cost if squared else np.sqrt(cost)
        rows, cols = linear_sum_assignment(cost)
        assert emd(a, b, squared=squared) == pytest.approx(cost[rows, cols].mean(), rel=1e-7)


def test_emd_drops_particles_that_left_and_rejects_an_empty_set():
    a = np.array([[0.0, 0, 0], [1.0, 0, 0], [np.nan, np.nan, np.nan]])
    assert emd(a, a[:2]) == 0.0
    with pytest.raises(InputError, match=r"empty.*sink"):
        emd(a, np.full((2, 3), np.nan))
    assert emd(np.full((2, 3), np.nan), np.full((3, 3), np.nan)) == 0.0  # both drained


@pytest.mark.parametrize("row", [[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0], [0.0, 0.0, np.nan]])
def test_emd_refuses_rows_with_nan_in_only_some_coordinates(row):
    a = np.array([[0.0, 0, 0], [1.0, 0, 0], row])
    with pytest.raises(InputError, match="only some coordinates"):
        emd(a, a[:2])
    with pytest.raises(InputError, match="only some coordinates"):
        emd(a[:2], a)


def test_an_empty_set_stands_at_the_sink():
    """One side drained: the other's particles all move to the outlet point (the paper's EMD
    against one particle there), for W2^2 and W1 and on either side."""
    pts = np.array([[0.0, 0.0, 0.3], [0.4, 0.0, 0.0], [np.nan] * 3])
    sink = np.array([0.0, 0.0, 0.0])
    gone = np.full((3, 3), np.nan)
    assert emd(pts, gone, sink=sink) == pytest.approx((0.09 + 0.16) / 2)
    assert emd(gone, pts, sink=sink) == pytest.approx((0.09 + 0.16) / 2)
    assert emd(pts, gone, squared=False, sink=sink) == pytest.approx((0.3 + 0.4) / 2)
    # Continuous with one particle left at the sink.
    assert emd(pts, sink[None], sink=sink) == emd(pts, gone, sink=sink)
    with pytest.raises(InputError, match="sink"):
        emd(pts, gone, sink=np.array([0.0, np.nan, 0.0]))


def test_the_outlet_point_lies_on_the_outflow_under_the_lid():
    hopper = make_hopper(num_particles=100)
    assert outlet_point(hopper).tolist() == pytest.approx([0.0, 0.0, hopper.outflow_z])
    drum = make_drum(num_particles=100)  # closed: the box's floor under its centre
    assert outlet_point(drum).tolist() == pytest.approx([0.0, 0.0, drum.domain_lo[2]])


def test_emd_at_powers_takes_every_frame_two_to_the_k():
    truth = np.zeros((20, 4, 3))
    pred = truth.copy()
    pred[:, :, 0] = np.arange(20)[:, None]  # frame f shifted by f along x
    out = emd_at_powers(truth, pred[:11])
    assert list(out) == [1, 2, 4, 8]
    assert out == {s: pytest.approx(float(s * s)) for s in (1, 2, 4, 8)}
    drained = truth.copy()
    drained[4:] = np.nan  # every particle has left the truth from frame 4 on
    with pytest.raises(InputError, match="sink"):
        emd_at_powers(drained, pred)  # a drained frame is never silently left out
    sink = np.array([0.0, 0.0, -1.0])
    out = emd_at_powers(drained, pred, sink=sink)
    assert list(out) == [1, 2, 4, 8, 16]
    assert out[16] == pytest.approx(16.0**2 + 1.0)  # every pred particle to the sink
    both = emd_at_powers(drained, drained, sink=sink)
    assert list(both) == [1, 2, 4, 8, 16] and both[8] == 0.0  # both drained: equal


# --- position error -------------------------------------------------------------------------


def test_position_mse_averages_over_particles_present_in_both():
    truth = np.zeros((2, 3, 3))
    pred = truth.copy()
    pred[1, 0] = [3.0, 0.0, 0.0]  # squared error 9 over 3 coordinates
    pred[1, 2] = np.nan
    assert position_mse(truth, pred).tolist() == [0.0, pytest.approx(9.0 / 3 / 2)]


# --- mixing entropy -------------------------------------------------------------------------


def _grid(bins: int, per_cell: int) -> np.ndarray:
    centres = (np.stack(np.meshgrid(*[np.arange(bins)] * 3, indexing="ij"), -1) + 0.5) / bins
    return np.repeat(centres.reshape(-1, 3), per_cell, axis=0)


def test_mixing_entropy_is_log2_for_a_perfectly_mixed_grid():
    pos = _grid(9, 2)
    classes = np.tile([1, -1], len(pos) // 2)
    assert mixing_entropy(pos, classes) == pytest.approx(math.log(2), rel=1e-12)


def test_mixing_entropy_is_zero_for_a_segregated_grid():
    pos = _grid(9, 2)
    classes = np.where(pos[:, 2] > 0.5, 1, -1)
    assert mixing_entropy(pos, classes) == pytest.approx(0.0, abs=1e-15)


def test_mixing_entropy_matches_the_formula_in_one_cell():
    pos = np.zeros((4, 3))
    classes = np.array([1, -1, -1, -1])
    f = np.array([0.25, 0.75])
    assert mixing_entropy(pos, classes, bins=1) == pytest.approx(-(f * np.log(f)).sum())


def test_mixing_classes_split_at_the_median_of_frame_t0_and_the_curve_rises_when_mixed():
    rng = np.random.default_rng(3)
    start = rng.uniform(size=(200, 3))
    positions = np.stack([start, start, rng.uniform(size=(200, 3))])
    classes = mixing_classes(positions, frame=1, axis=2)
    assert (classes == 1).sum() == 100 and (classes == -1).sum() == 100
    curve = mixing_entropy_curve(positions, classes, bins=3)
    assert curve[0] == curve[1] < 0.3 < curve[2]
    with pytest.raises(InputError, match="frame"):
        mixing_classes(positions, frame=5)


# --- flow profile ---------------------------------------------------------------------------


def test_flow_profile_averages_the_velocity_per_height_bin():
    pos = np.array([[[0, 0, 0.1], [0, 0, 0.2], [0, 0, 0.9], [np.nan] * 3]])
    vel = np.array([[[0, 0, -1.0], [0, 0, -3.0], [0, 0, 5.0], [0, 0, 7.0]]])
    prof = flow_profile(pos, vel, z_bins=2, z_range=(0.0, 1.0))
    assert prof.tolist() == [[-2.0, 5.0]]
    empty = flow_profile(pos, vel, z_bins=4, z_range=(0.0, 1.0))
    assert np.isnan(empty[0, 2])


# --- hopper discharge -----------------------------------------------------------------------


def test_discharge_rate_of_a_synthetic_steady_discharge():
    # 100 particles of 2 g leave one by one every 10 ms: 0.2 kg/s.
    n, dt = 100, 0.01
    times = np.arange(0, 1.2, 0.001)
    leave = 0.1 + dt * np.arange(n)
    z = np.where(times[:, None] < leave[None], 0.05, np.nan)
    positions = np.zeros((len(times), n, 3))
    positions[..., 2] = z
    rate, (t0, t1) = discharge_rate(times, positions, outlet_z=0.0, mass=np.full(n, 0.002))
    assert rate == pytest.approx(0.2, rel=0.02)
    assert 0.1 < t0 < t1 < 1.1
    with pytest.raises(InputError, match="too little discharge"):
        discharge_rate(times, np.full_like(positions, 0.05), outlet_z=0.0, mass=np.ones(n))


# --- drum angle of repose -------------------------------------------------------------------


@pytest.mark.parametrize("angle", [15.0, 30.0, 40.0])
def test_angle_of_repose_of_a_synthetic_tilted_bed(angle):
    # A bed inside a circle of radius 0.05 (x-z plane) below a plane tilted by `angle`.
    rng = np.random.default_rng(int(angle))
    pts = rng.uniform(-0.05, 0.05, size=(60000, 3))
    pts[:, 1] *= 0.2
    slope = math.tan(math.radians(angle))
    bed = (np.hypot(pts[:, 0], pts[:, 2]) < 0.05) & (pts[:, 2] < slope * pts[:, 0])
    got = dynamic_angle_of_repose(pts[bed], axis=1)
    assert abs(got - angle) < 0.5


def test_crushed_particles_counts_centres_closer_than_the_distance():
    frame = np.array(
        [[0.0, 0, 0], [0.001, 0, 0], [0.01, 0, 0], [0.012, 0, 0], [np.nan, np.nan, np.nan]]
    )
    apart = frame.copy()
    apart[1, 0] = 0.004
    counts = crushed_particles(np.stack([frame, apart]), 0.0015)
    assert counts.tolist() == [2, 0]  # 1 mm apart: crushed; 2 mm and 4 mm apart: not


def test_crushed_particles_matches_brute_force():
    rng = np.random.default_rng(3)
    pos = rng.uniform(0, 0.02, size=(4, 300, 3))
    pos[2, :40] = np.nan
    counts = crushed_particles(pos, 0.0015)
    for f in range(4):
        p = pos[f][np.isfinite(pos[f]).all(1)]
        d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(len(p))
        assert counts[f] == int((d < 0.0015).any(1).sum())
    with pytest.raises(InputError, match="distance"):
        crushed_particles(pos, 0.0)


# --- what a scene's kind says -----------------------------------------------------------------


def test_the_drum_axis_comes_from_the_rotating_wall():
    import dataclasses

    from granular_pyg.metrics import drum_axis, outlet_height
    from granular_pyg.scenes import WallMotion

    drum = make_drum(num_particles=100)
    np.testing.assert_allclose(drum_axis(drum), [0.0, 1.0, 0.0])
    h = np.hypot(0.2, 0.9)
    for axis, expected in [
        ((1.0, 0.0, 0.0), [1.0, 0.0, 0.0]),
        ((0.2, -0.9, 0.1), [0.2 / h, -0.9 / h, 0.0]),  # any horizontal direction
        ((0.1, 0.1, 1.0), None),
    ]:
        wall = dataclasses.replace(drum.walls[0], motion=WallMotion("rotation", axis=axis, omega=2))
        got = drum_axis(dataclasses.replace(drum, walls=[wall]))
        if expected is None:
            assert got is None
        else:
            np.testing.assert_allclose(got, expected, atol=1e-12)
    hopper = make_hopper(num_particles=100)
    assert drum_axis(hopper) is None
    assert outlet_height(hopper) == 0.0  # the builder's outlet
    hopper.params["outlet_z"] = 0.02
    assert outlet_height(hopper) == 0.02


def test_centre_of_mass_swing_is_the_amplitude_after_the_settling_time():
    times = np.arange(8) * 0.25  # 0 ... 1.75 s
    centres = np.zeros((8, 3))
    centres[:4, 0] = 1.0  # a big swing before 1 s does not count
    centres[4:, 0] = [0.002, -0.002, 0.002, -0.002]  # +-2 mm about 0 from 1 s on
    centres[5, :] = np.nan  # a frame without particles is left out
    swing = centre_of_mass_swing(centres, times, after=1.0)
    assert swing == pytest.approx(
        0.002 + 0.002 / 3, rel=1e-12
    )  # 2, 2, -2 mm: mean 2/3 mm, farthest 8/3 mm
    assert np.isnan(centre_of_mass_swing(centres, times, after=1.75))
