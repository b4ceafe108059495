"""WallSet.contain (the rollout's wall guard): moves through walls stop at them, others do not
change, a rotating drum is followed, corners hold, and the lid counts only while it is there."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from granular_pyg.errors import InputError
from granular_pyg.metrics import leaked_mask
from granular_pyg.scenes import WallSet, make_drum, make_hopper

RADIUS = 0.0015
CUTOFF = 0.0075  # the smallest wall-index query radius (m)


def _inside_hopper(rng, n, scene, lo=0.004, hi=0.06):
    """``[n, 3]`` centres inside the V, at least ``RADIUS`` from every wall."""
    p = scene.params
    tan_a = math.tan(math.radians(p["alpha_deg"]))
    z = rng.uniform(lo, hi, n)
    half = p["opening"] / 2 + z / tan_a - RADIUS / math.sin(math.radians(p["alpha_deg"]))
    x = rng.uniform(-1, 1, n) * half
    y = rng.uniform(-1, 1, n) * (p["depth"] / 2 - RADIUS)
    return np.stack([x, y, z], 1)


def test_hopper_moves_through_a_wall_end_inside_and_the_others_are_untouched():
    scene = make_hopper()
    walls = WallSet(scene)
    rng = np.random.default_rng(3)
    start = _inside_hopper(rng, 3000, scene)
    end = start + rng.normal(scale=0.006, size=start.shape)
    end[:, 2] = np.clip(end[:, 2], 0.002, 0.09)  # stay above the outlet and below the top edge
    t = np.array([0.1])
    through = leaked_mask(end[None], scene, t)[0]
    assert 300 < through.sum() < 2900

    new, corrected = walls.contain(
        torch.from_numpy(start), torch.from_numpy(end), 0.1, 0.1, RADIUS, CUTOFF
    )
    new = new.numpy()
    assert corrected == through.sum()
    assert not leaked_mask(new[None], scene, t)[0].any()
    assert np.array_equal(new[~through], end[~through])  # bit for bit
    # The corrected centres sit on the start's side, at most RADIUS from a wall's plane, and
    # keep the motion along the wall: they moved no farther than their proposed end.
    moved = np.linalg.norm(new[through] - start[through], axis=1)
    proposed = np.linalg.norm(end[through] - start[through], axis=1)
    assert (moved <= proposed + 1e-12).all()


def test_a_move_into_the_corner_of_two_walls_is_held_by_both():
    scene = make_hopper()
    p = scene.params
    tan_a = math.tan(math.radians(p["alpha_deg"]))
    z = 0.03
    corner = np.array([p["opening"] / 2 + z / tan_a, p["depth"] / 2, z])
    start = corner - np.array([0.004, 0.004, 0.0])
    end = corner + np.array([0.004, 0.003, -0.001])  # out through the V and the front wall
    new, corrected = WallSet(scene).contain(
        torch.from_numpy(start[None]), torch.from_numpy(end[None]), 0.1, 0.1, RADIUS, CUTOFF
    )
    assert corrected == 1
    assert not leaked_mask(new.numpy()[None], scene, np.array([0.1]))[0].any()


def test_the_lid_holds_the_bed_until_t_open_only():
    scene = make_hopper(t_open=0.05)
    start = torch.tensor([[0.0, 0.0, 0.002]], dtype=torch.float64)
    end = torch.tensor([[0.0, 0.0, -0.004]], dtype=torch.float64)
    walls = WallSet(scene)
    held, corrected = walls.contain(start, end, 0.04, 0.045, RADIUS, CUTOFF)
    assert corrected == 1 and 0.0 < held[0, 2].item() <= 0.002
    free, corrected = walls.contain(start, end, 0.05, 0.055, RADIUS, CUTOFF)
    assert corrected == 0 and torch.equal(free, end)


def test_the_guard_follows_a_rotating_drum():
    scene = make_drum(omega=2.0)
    walls = WallSet(scene)
    radius = scene.params["drum_radius"]
    rng = np.random.default_rng(5)
    n = 2000
    phi = rng.uniform(0, 2 * np.pi, n)
    r = rng.uniform(0.8, 0.95, n) * radius * math.cos(math.pi / 48)
    y = rng.uniform(-0.01, 0.01, n)
    start = np.stack([r * np.cos(phi), y, r * np.sin(phi)], 1)
    t0, t1 = 0.30, 0.32
    # Carried along by the drum: a rigid rotation by omega * dt about +y never crosses it.
    rot0, _ = scene.walls[0].motion.pose(t0)
    rot1, _ = scene.walls[0].motion.pose(t1)
    carried = start @ rot0 @ rot1.T
    same, corrected = walls.contain(
        torch.from_numpy(start), torch.from_numpy(carried), t0, t1, 0.002, CUTOFF
    )
    assert corrected == 0 and np.array_equal(same.numpy(), carried)
    # Thrown outwards 2 cm: every particle is held inside the shell.
    out = carried * (1 + 0.02 / r)[:, None]
    held, corrected = walls.contain(
        torch.from_numpy(start), torch.from_numpy(out), t0, t1, 0.002, CUTOFF
    )
    held = held.numpy()
    assert corrected == n
    assert (np.hypot(held[:, 0], held[:, 2]) < radius).all()
    assert not leaked_mask(held[None], scene, np.array([t1]))[0].any()


def test_the_guard_needs_a_positive_margin():
    walls = WallSet(make_hopper())
    p = torch.zeros((1, 3), dtype=torch.float64) + 0.01
    with pytest.raises(InputError, match="margin"):
        walls.contain(p, p, 0.0, 0.01, 0.0, CUTOFF)


def test_a_centre_creeping_up_to_the_shell_stays_inside_for_good():
    """The drum case that leaked: a particle riding the turning shell, each learned step
    carrying it a little further out (here 70% of its gap, then a step through the shell),
    in float32 as in a rollout. The guard keeps it 2 * GUARD_SKIN * margin or more inside, so
    round-off never puts it on the plane (without the skin it was through after ~30 steps)."""
    from granular_pyg.scenes.wall_set import GUARD_SKIN

    scene = make_drum(omega=2.0)
    walls = WallSet(scene)
    rot, _ = scene.walls[0].motion.pose(0.0)
    # On the middle of a facet's plane (the 48 facets' vertices lie on the circle), 0.15 mm in.
    facet = scene.params["drum_radius"] * math.cos(math.pi / 48)
    angle = 2 * math.pi * 10.5 / 48
    mid = torch.tensor([[math.cos(angle), 0.004, math.sin(angle)]], dtype=torch.float64)
    facet_frame_gap = facet - 1.5e-4
    pos = (mid * torch.tensor([facet_frame_gap, 1.0, facet_frame_gap])).float() @ torch.from_numpy(
        rot
    ).float()
    margin, dt = 0.002, 0.02
    outward = torch.tensor([[math.cos(angle), 0.0, math.sin(angle)]])
    gaps = []
    for s in range(120):
        t0, t1 = s * dt, (s + 1) * dt
        rot0, _ = scene.walls[0].motion.pose(t0)
        rot1, _ = scene.walls[0].motion.pose(t1)
        carried = (pos.double() @ torch.from_numpy(rot0 @ rot1.T)).float()  # with the shell
        direction = outward.double() @ torch.from_numpy(rot1.T)
        gap = facet - float((carried.double() * direction).sum())
        step = 0.7 * gap if s % 3 else gap + 1e-3  # creep, then through
        end = (carried.double() + step * direction).float()
        pos, _ = walls.contain(pos, end, t0, t1, margin, CUTOFF)
        gaps.append(facet - float((pos.double() * direction).sum()))
    assert min(gaps) >= 2 * GUARD_SKIN * margin * 0.999
    assert not leaked_mask(pos.double().numpy()[None], scene, np.array([120 * dt]))[0].any()
