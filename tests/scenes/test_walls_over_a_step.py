"""How a learned step sees the walls over it (``WallSet.contacts(..., step_end=...)``): the walls
present at its end, moving with their mean velocity over it, against brute-force averages."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from granular_pyg.scenes import Wall, WallMotion, WallSet

MOTIONS = [
    WallMotion("rotation", axis=(0.0, 1.0, 0.0), omega=2.0, start_time=0.11, stop_time=0.52),
    WallMotion("translation", velocity=(0.1, -0.2, 0.05), start_time=0.11, stop_time=0.52),
    WallMotion("oscillation", amplitude=(0.01, 0.0, 0.02), period=0.07, start_time=0.11),
    WallMotion(
        "rotation", axis=(1.0, 0.0, 0.0), omega=-3.0, start_time=0.11, reverse_times=(0.22, 0.305)
    ),
]
STEPS = [(0.0, 0.1), (0.1, 0.14), (0.5, 0.54), (0.2, 0.24), (0.6, 0.64), (0.3, 0.31)]


def _brute_mean(motion: WallMotion, t0: float, t1: float, samples: int):
    """Mid-point averages over [t0, t1] of the wall's angular and linear velocity."""
    ts = t0 + (np.arange(samples) + 0.5) * (t1 - t0) / samples
    spin = np.mean([motion.angular_velocity(t) for t in ts])
    return spin, np.mean([motion.linear_velocity(t) for t in ts], axis=0)


@pytest.mark.parametrize("motion", MOTIONS, ids=lambda m: m.kind)
@pytest.mark.parametrize(("t0", "t1"), STEPS)
def test_mean_motion_over_a_step_matches_the_brute_force_average(motion, t0, t1):
    samples = 20_001  # a jump at a start, stop or reversal costs the mid-point rule a sample
    spin, velocity = _brute_mean(motion, t0, t1, samples)
    rate = abs(motion.omega)
    assert motion.mean_angular_velocity(t0, t1) == pytest.approx(spin, abs=2 * rate / samples)
    np.testing.assert_allclose(motion.mean_linear_velocity(t0, t1), velocity, atol=2.0 / samples)


def test_a_static_wall_never_moves_and_an_empty_step_is_still():
    assert WallMotion().mean_angular_velocity(0.0, 1.0) == 0.0
    assert MOTIONS[0].mean_angular_velocity(0.3, 0.3) == 0.0
    np.testing.assert_array_equal(MOTIONS[1].mean_linear_velocity(0.3, 0.3), np.zeros(3))


def _floor(motion: WallMotion, removal_time: float | None = None) -> WallSet:
    vertices = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    return WallSet([Wall("floor", vertices, np.array([[0, 1, 2]]), motion, removal_time)])


def test_contacts_over_a_step_carry_the_mean_velocity_and_the_end_s_walls():
    points = torch.tensor([[0.1, 0.2, 0.001], [-0.3, 0.0, 0.002]], dtype=torch.float64)
    spin = MOTIONS[0]
    walls = _floor(spin)
    at_start = walls.contacts(points, 0.005, 0.1)  # the drum still at rest at 0.1 s
    assert torch.count_nonzero(at_start.velocity) == 0
    over = walls.contacts(points, 0.005, 0.1, step_end=0.14)  # it starts at 0.11 s
    omega = torch.tensor([0.0, 2.0, 0.0], dtype=torch.float64).expand_as(over.closest)
    spinning = torch.linalg.cross(omega, over.closest)  # about the y axis through the origin
    torch.testing.assert_close(over.velocity, 0.75 * spinning)  # 30 of the step's 40 ms
    torch.testing.assert_close(over.closest, at_start.closest)  # poses at the step's start
    lid = _floor(WallMotion(), removal_time=0.12)
    assert len(lid.contacts(points, 0.005, 0.1).point_idx) == 2
    assert len(lid.contacts(points, 0.005, 0.1, step_end=0.14).point_idx) == 0
    # removed at the step's very end: it held the bed for the whole step (the truth has not
    # moved yet); a frame earlier, it is gone
    assert len(lid.contacts(points, 0.005, 0.1, step_end=0.12).point_idx) == 2
    assert len(lid.contacts(points, 0.005, 0.1, step_end=0.1225).point_idx) == 0
    assert len(lid.contacts(points, 0.005, 0.08, step_end=0.11).point_idx) == 2


def test_a_drum_reversing_mid_step_carries_the_net_turn_over_the_step():
    points = torch.tensor([[0.1, 0.2, 0.001], [-0.3, 0.0, 0.002]], dtype=torch.float64)
    back = WallMotion("rotation", axis=(0.0, 1.0, 0.0), omega=2.0, reverse_times=(0.13,))
    walls = _floor(back)
    over = walls.contacts(points, 0.005, 0.1, step_end=0.14)  # 30 ms forward, 10 ms back
    at_start = walls.contacts(points, 0.005, 0.1)
    torch.testing.assert_close(over.velocity, 0.5 * at_start.velocity)
    after = walls.contacts(points, 0.005, 0.15)  # turning the other way at full speed
    torch.testing.assert_close(after.velocity, -at_start.velocity, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("motion", "removal", "t0", "t1", "changes"),
    [
        (WallMotion(), None, 0.0, 1.0, False),  # static, never removed
        (WallMotion(), 0.5, 0.46, 0.5, True),  # removed at the step's end
        (WallMotion(), 0.5, 0.5, 0.54, True),  # removed at its start: the history had it
        (WallMotion(), 0.5, 0.51, 0.55, False),  # gone before the step
        (MOTIONS[0], None, 0.1, 0.14, True),  # the drum starts at 0.11 s
        (MOTIONS[0], None, 0.2, 0.24, False),  # turning steadily
        (MOTIONS[0], None, 0.5, 0.54, True),  # and stops at 0.52 s
        (MOTIONS[3], None, 0.3, 0.31, True),  # turns back at 0.305 s
        (MOTIONS[2], None, 0.2, 0.24, False),  # an oscillation changes smoothly
    ],
)
def test_changing_names_the_walls_a_step_removes_starts_stops_or_reverses(
    motion, removal, t0, t1, changes
):
    assert _floor(motion, removal).changing(t0, t1) == ([0] if changes else [])


def test_near_finds_the_points_within_reach_of_the_given_walls_at_their_pose():
    """A floor turned 90 degrees about y by t = 0.5 s lies in the y-z plane: the points near it
    are those of small |x|, whatever their height; against the distances by brute force."""
    walls = _floor(WallMotion("rotation", axis=(0.0, 1.0, 0.0), omega=np.pi))
    points = torch.tensor(
        [[0.004, 0.0, 0.1], [0.02, 0.1, -0.2], [0.0, 0.0, 0.0], [-0.015, -0.3, 0.3]],
        dtype=torch.float64,
    )
    near = walls.near(points, 0.0125, 0.5, [0])
    x_world = walls.walls[0].vertices_at(0.5)[:, 0]
    np.testing.assert_allclose(x_world, 0.0, atol=1e-12)  # the turned floor: x = 0
    assert near.tolist() == [True, False, True, False]
    assert not walls.near(points, 0.0125, 0.5, []).any()
