"""Discharge metrics against the initial bed, time to empty, Beverloo's rate and the outlet a
Scene describes: tiny exact cases, brute force, and frame invariance (turning the scene about
gravity or mirroring it changes no number)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from granular_pyg.errors import InputError
from granular_pyg.metrics.beverloo import (
    C_CIRCLE,
    C_SLOT,
    Outlet,
    beverloo_rate,
    outlet_of,
    scene_beverloo_rate,
)
from granular_pyg.metrics.flow import bed_mass, discharge_curve, discharge_rate, time_to_empty
from granular_pyg.scenes import make_hopper
from granular_pyg.scenes.scene import Wall


def _leaving(times: np.ndarray, leave: np.ndarray, z: float = 0.05) -> np.ndarray:
    """``[T, N, 3]``: particle i at height ``z`` until ``leave[i]``, gone (NaN) after."""
    pos = np.zeros((len(times), len(leave), 3))
    pos[..., 2] = np.where(times[:, None] < leave[None], z, np.nan)
    pos[..., 0] = np.linspace(-0.01, 0.02, len(leave))[None]
    pos[..., 1] = np.linspace(0.005, -0.01, len(leave))[None]
    return pos


def test_the_discharge_curve_counts_the_initial_bed_only():
    # 3 particles: one above the outlet that falls through, one that stays, one below at t=0.
    pos = np.array(
        [
            [[0, 0, 0.02], [0, 0, 0.03], [0, 0, -0.01]],
            [[0, 0, -0.001], [0, 0, 0.03], [np.nan] * 3],
        ]
    )
    mass = np.array([1.0, 2.0, 4.0])
    assert discharge_curve(pos, 0.0, mass).tolist() == [0.0, 1.0]
    assert bed_mass(pos, 0.0, mass) == 3.0
    with pytest.raises(InputError, match="mass"):
        discharge_curve(pos, 0.0, np.ones(2))


def test_the_rate_of_a_steady_discharge_matches_a_brute_force_fit():
    rng = np.random.default_rng(0)
    n = 120
    times = np.arange(0.0, 1.5, 0.005)
    leave = np.sort(rng.uniform(0.1, 1.2, n))
    mass = rng.uniform(1e-3, 3e-3, n)
    pos = _leaving(times, leave)
    rate, (t0, t1) = discharge_rate(times, pos, 0.0, mass)
    # Brute force: the discharged mass frame by frame, the window by the initial bed.
    curve = np.array(
        [sum(m for m, t_l in zip(mass, leave, strict=True) if t >= t_l) for t in times]
    )
    inside = (np.arange(len(times)) >= np.argmax(curve >= 0.2 * mass.sum())) & (
        np.arange(len(times)) <= np.argmax(curve >= 0.8 * mass.sum())
    )
    assert rate == pytest.approx(np.polyfit(times[inside], curve[inside], 1)[0], rel=1e-9)
    assert (t0, t1) == (times[inside][0], times[inside][-1])


def test_a_rollout_that_stalls_is_measured_against_the_initial_bed():
    """Truth empties at 0.2 kg/s; the rollout flows at the same rate, then stops with half its
    bed inside. Fitted against its own final mass (the old metric) the two rates agree; against
    the initial bed the stall shows: a lower rate, half the bed left, never empty."""
    n, times = 100, np.arange(0.0, 1.5, 0.002)
    leave = 0.1 + 0.01 * np.arange(n)
    stalled = np.where(np.arange(n) < 50, leave, np.inf)
    mass = np.full(n, 0.002)
    truth, pred = _leaving(times, leave), _leaving(times, stalled)
    r_t = discharge_rate(times, truth, 0.0, mass)[0]
    r_p = discharge_rate(times, pred, 0.0, mass)[0]
    assert r_t == pytest.approx(0.2, rel=0.02)
    assert r_p < 0.5 * r_t
    assert discharge_curve(pred, 0.0, mass)[-1] / bed_mass(pred, 0.0, mass) == pytest.approx(0.5)
    assert time_to_empty(times, truth, 0.0, mass, since=0.1) == pytest.approx(0.98, abs=0.003)
    assert math.isnan(time_to_empty(times, pred, 0.0, mass))
    with pytest.raises(InputError, match="too little discharge"):
        discharge_rate(times, _leaving(times, np.full(n, np.inf)), 0.0, mass)


@pytest.mark.parametrize("angle", [0.3, 1.7, 4.0])
def test_discharge_metrics_do_not_depend_on_the_frame(angle):
    rng = np.random.default_rng(1)
    n, times = 80, np.arange(0.0, 1.2, 0.004)
    pos = _leaving(times, np.sort(rng.uniform(0.05, 1.0, n)))
    pos[..., :2] += rng.normal(0, 0.01, (1, n, 2))
    mass = rng.uniform(1e-3, 2e-3, n)
    c, s = math.cos(angle), math.sin(angle)
    turn = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    mirror = np.diag([-1.0, 1.0, 1.0])
    for frame in (turn, mirror, turn @ mirror):
        moved = pos @ frame.T
        assert discharge_rate(times, moved, 0.0, mass) == discharge_rate(times, pos, 0.0, mass)
        assert time_to_empty(times, moved, 0.0, mass) == time_to_empty(times, pos, 0.0, mass)


def test_beverloo_rates_of_each_outlet_shape():
    d, rho, g = 0.002, 2500.0, 9.81
    rho_b = 0.6 * rho
    circle = beverloo_rate(Outlet("circle", 0.02, 0.02), d, rho, g)
    assert circle == pytest.approx(C_CIRCLE * rho_b * math.sqrt(g) * 0.017**2.5, rel=1e-12)
    slot = beverloo_rate(Outlet("slot", 0.015, 0.03), d, rho, g)
    assert slot == pytest.approx(C_SLOT * rho_b * math.sqrt(g) * 0.03 * 0.012**1.5, rel=1e-12)
    rect = beverloo_rate(Outlet("rectangle", 0.015, 0.03), d, rho, g)
    assert rect == pytest.approx(slot * 0.027 / 0.03, rel=1e-12)
    assert beverloo_rate(Outlet("circle", 0.0029, 0.0029), d, rho, g) == 0.0  # narrower than kd


def _plate_with_hole(hole: np.ndarray) -> Wall:
    """A flat ring at z = 0 around the convex polygon ``hole [K, 2]`` (m): a strip of quads
    out to the hole scaled by 3 about its centre (two open loops; the hole is the smaller)."""
    centre = hole.mean(0)
    ring = np.concatenate([hole, centre + 3 * (hole - centre)])
    k = len(hole)
    i, j = np.arange(k), (np.arange(k) + 1) % k
    faces = np.concatenate([np.stack([i, j, k + j], 1), np.stack([i, k + j, k + i], 1)])
    return Wall("plate", np.column_stack([ring, np.zeros(len(ring))]), faces)


def _mesh_hopper(hole: np.ndarray):
    base = make_hopper()
    lid = dataclasses.replace(base.walls[1], name="lid")
    return dataclasses.replace(base, walls=[_plate_with_hole(hole), lid], params={"outlet_z": 0.0})


def test_the_outlet_of_a_mesh_is_read_from_its_hole():
    theta = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    circle = _mesh_hopper(0.01 * np.column_stack([np.cos(theta), np.sin(theta)]) + [0.01, 0])
    found = outlet_of(circle)
    assert found.shape == "circle" and found.source == "mesh"
    assert found.width == pytest.approx(0.02, rel=0.005)
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    square = _mesh_hopper(0.007 * corners)
    found = outlet_of(square)
    assert found.shape == "rectangle"
    assert (found.width, found.length) == pytest.approx((0.014, 0.014), rel=1e-6)
    slot = _mesh_hopper(corners * [0.005, 0.02])
    assert (outlet_of(slot).width, outlet_of(slot).length) == pytest.approx((0.01, 0.04), rel=1e-6)


@pytest.mark.parametrize("angle", [0.5, 2.0])
def test_the_outlet_and_beverloo_do_not_depend_on_the_frame(angle):
    theta = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    scene = _mesh_hopper(0.009 * np.column_stack([np.cos(theta), np.sin(theta)]) + [0.012, 0.003])
    c, s = math.cos(angle), math.sin(angle)
    for frame in (np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), np.diag([1.0, -1.0, 1.0])):
        walls = [dataclasses.replace(w, vertices=w.vertices @ frame.T) for w in scene.walls]
        moved = dataclasses.replace(scene, walls=walls)
        radii = np.full(10, 0.001)
        assert scene_beverloo_rate(moved, radii) == pytest.approx(
            scene_beverloo_rate(scene, radii), rel=1e-9
        )


def test_the_built_in_hopper_has_a_wall_to_wall_slot():
    scene = make_hopper(opening=0.018, depth=0.03)
    assert outlet_of(scene) == Outlet("slot", 0.018, 0.03, "params")
    # Without its params the same slot is read from the mesh, as a rectangle.
    found = outlet_of(dataclasses.replace(scene, params={}))
    assert found.shape == "rectangle"
    assert (found.width, found.length) == pytest.approx((0.018, 0.03), rel=1e-9)


def test_frames_before_first_frame_are_left_out_of_the_fit():
    """A rollout's copied initial states are the truth's: a window among them measures nothing
    of the model, so the fit starts at ``first_frame`` (and fails if 80% was passed before)."""
    n, times = 100, np.arange(0.0, 1.5, 0.01)
    pos = _leaving(times, 0.1 + 0.01 * np.arange(n))
    mass = np.full(n, 0.002)
    rate, (t0, _) = discharge_rate(times, pos, 0.0, mass, first_frame=50)
    assert t0 == times[50] and rate == pytest.approx(0.2, rel=0.05)
    with pytest.raises(InputError, match="too little discharge"):
        discharge_rate(times, pos, 0.0, mass, first_frame=100)


def test_a_drain_within_a_few_coarse_frames_still_has_its_rate():
    """A rollout whose learned steps are coarse against a fast drain (two frames inside the
    20-80% window) gets the mean rate between the window's crossings, exact for a steady
    drain; the same drain on fine frames gets it from the fit."""
    n = 100
    mass = np.full(n, 0.002)
    leave = 0.1 + 0.001 * np.arange(n)  # 2 kg/s from t = 0.1 to 0.2 s
    coarse = np.arange(0.0, 0.4, 0.05)
    rate, (t0, t1) = discharge_rate(coarse, _leaving(coarse, leave), 0.0, mass)
    # Brute force: the curve on the frames (0.002 kg at 0.1 s, 0.102 at 0.15, 0.2 at 0.2:
    # two frames in the window, no fit), joined linearly through 20% and 80% (0.04, 0.16 kg).
    curve = np.array([(leave <= t).sum() * 0.002 for t in coarse])
    assert curve[2:5] == pytest.approx([0.002, 0.102, 0.2])
    lo_t = np.interp(0.04, curve, coarse)
    hi_t = np.interp(0.16, curve, coarse)
    assert (t0, t1) == pytest.approx((lo_t, hi_t), abs=1e-12)
    assert rate == pytest.approx(0.12 / (hi_t - lo_t), rel=1e-12)
    fine = np.arange(0.0, 0.4, 0.001)
    assert discharge_rate(fine, _leaving(fine, leave), 0.0, mass)[0] == pytest.approx(2.0, rel=0.01)
    assert rate == pytest.approx(2.0, rel=0.02)
    # A window passed entirely among the copied initial frames still measures nothing.
    with pytest.raises(InputError, match="too little discharge"):
        discharge_rate(coarse, _leaving(coarse, leave), 0.0, mass, first_frame=4)
