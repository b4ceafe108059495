"""Leaked particles from the Scene's real walls: moves through a triangle (the wall guard's test,
no skin), centres outside a closed surface, outside the box; checked by hand and against a dense
all-pairs loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from granular_pyg.geometry import segment_triangle_crossings
from granular_pyg.metrics import leaked_mask, leaked_particles
from granular_pyg.scenes import (
    ParticleSpec,
    Scene,
    Wall,
    WallMotion,
    WallSet,
    make_drum,
    make_hopper,
)

H = 0.1  # m, the V's height and half width


def _v_scene(outflow: bool = False) -> Scene:
    """A concave V along y (valley x = 0, z = 0; arms up to x = +-H at z = H), each arm a quad
    of two triangles whose diagonal runs from (0, -H, 0) to (-+H, H, H)."""
    vertices = np.array(
        [
            [0.0, -H, 0.0], [0.0, H, 0.0],  # the valley
            [-H, -H, H], [-H, H, H],  # left rim
            [H, -H, H], [H, H, H],  # right rim
        ]
    )  # fmt: skip
    faces = np.array([[0, 1, 3], [0, 3, 2], [0, 4, 5], [0, 5, 1]])
    lo = (-2 * H, -2 * H, -H)
    return Scene(
        name="v_trough",
        kind="other",
        walls=[Wall("v", vertices, faces)],
        particles=ParticleSpec(10, 0.001, (-0.01, -0.01, 0.05), (0.01, 0.01, 0.06)),
        domain_lo=lo,
        domain_hi=(2 * H, 2 * H, 2 * H),
        outflow_z=lo[2] if outflow else None,
    )


def _mask(scene, *frames, times=None):
    pos = np.array(frames, dtype=np.float64)
    times = np.arange(len(pos)) * 0.01 if times is None else np.asarray(times, float)
    return leaked_mask(pos, scene, times)


def test_a_move_through_an_arm_of_a_concave_v_leaks():
    scene = _v_scene()
    inside = [-0.02, 0.01, 0.05]  # above the left arm (z = -x there), 30 mm in
    through = [-0.05, 0.01, 0.02]  # below it
    mask = _mask(scene, [inside, inside], [inside, through])
    assert mask.tolist() == [[False, False], [False, True]]
    assert leaked_particles(np.array([[inside], [through]]), scene, np.array([0.0, 0.01])) == 1


def test_a_move_along_a_wall_or_up_to_it_does_not_leak():
    scene = _v_scene()
    gap = 0.001 * math.sqrt(2)  # 1 mm from the left arm's plane z = -x, measured along z
    along = ([-0.05, 0.0, 0.05 + gap], [-0.02, 0.03, 0.02 + gap])  # parallel to the arm
    short = ([-0.02, 0.0, 0.05], [-0.04, 0.0, 0.04 + 1e-4])  # stops 0.07 mm before it
    on_plane = ([-0.05, 0.0, 0.05], [-0.03, 0.01, 0.03])  # starts and ends on it: no side
    for start, end in (along, short, on_plane):
        assert not _mask(scene, [start], [end]).any()
    # The same arm, ending on its plane: the centre reached the wall, a leak.
    assert _mask(scene, [short[0]], [[-0.04, 0.0, 0.04]])[1, 0]


def test_a_move_through_a_shared_edge_is_one_leak():
    """Straight down through the valley (the edge of the left and the right arm) and through
    the diagonal shared by the left arm's two triangles: each pair of triangles is crossed, the
    particle counted once."""
    scene = _v_scene()
    starts = np.array([[0.0, 0.02, 0.05], [-0.05, 0.0, 0.06]])  # the diagonal's midpoint below
    ends = np.array([[0.0, 0.02, -0.05], [-0.05, 0.0, 0.04]])
    tris = torch.from_numpy(scene.walls[0].triangles)
    for start, end in zip(starts, ends, strict=True):
        hits = segment_triangle_crossings(
            torch.from_numpy(start).expand(4, 3), torch.from_numpy(end).expand(4, 3), tris
        ).crosses
        assert int(hits.sum()) == 2  # both triangles of the edge
    mask = leaked_mask(np.stack([starts, ends]), scene, np.array([0.0, 0.01]))
    assert mask.tolist() == [[False, False], [True, True]]
    assert leaked_particles(np.stack([starts, ends]), scene, np.array([0.0, 0.01])) == 2


def test_the_lid_holds_until_its_removal_time():
    """A centre from the outlet to below the outflow: through the lid while it is there (a
    leak), through the open outlet after (not one)."""
    scene = make_hopper(num_particles=100, t_open=0.05)
    above = [0.0, 0.0, 0.005]
    below = [0.001, 0.0, scene.outflow_z - 0.005]
    frames = np.array([[above], [below]])
    assert leaked_mask(frames, scene, np.array([0.03, 0.04]))[:, 0].tolist() == [False, True]
    assert not leaked_mask(frames, scene, np.array([0.06, 0.07])).any()
    # Below the outflow in its first frame: on its way out, not tested against the walls.
    assert not leaked_mask(frames[1:], scene, np.array([0.03])).any()


def test_a_turning_closed_drum_carries_its_bed_without_a_leak():
    scene = make_drum(num_particles=100, omega=2.0)
    rng = np.random.default_rng(0)
    n, radius = 500, scene.params["drum_radius"] * math.cos(math.pi / 48)
    phi, rho = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.0, 0.98, n) * radius
    y = rng.uniform(-0.0145, 0.0145, n)
    bed = np.stack([rho * np.cos(phi), y, rho * np.sin(phi)], 1)
    times = np.arange(40) * 0.05  # 4 rad: most of a turn
    # At rest in the drum's frame: each frame the bed rotated as the drum.
    pos = np.stack([bed @ scene.walls[0].motion.pose(t)[0].T for t in times])
    assert not leaked_mask(pos, scene, times).any()
    # One particle thrown out through the shell in the last frame, one outside from the start.
    pos[-1, 0] *= 1.1 * scene.params["drum_radius"] / np.linalg.norm(pos[-1, 0, [0, 2]])
    pos[:, 1, 1] = 0.02  # beyond an end cap (length 30 mm), inside the box
    mask = leaked_mask(pos, scene, times)
    assert np.flatnonzero(mask[:, 0]).tolist() == [39]
    assert np.flatnonzero(mask[:, 1]).tolist() == [0]  # its first frame: outside the surface
    assert leaked_particles(pos, scene, times) == 2


def test_a_box_leak_and_particles_that_left():
    scene = _v_scene(outflow=True)
    inside = [0.0, 0.0, 0.05]
    mask = _mask(
        scene,
        [inside, inside, inside, [np.nan] * 3],
        [[0.0, 0.0, 0.25], [0.0, 0.0, -0.2], inside, [np.nan] * 3],  # out over the top,
    )  # below the floor (through the valley: crossing)
    assert mask.tolist() == [[False] * 4, [True, True, False, False]]
    # Out of the V over its rim and out of the box: a box leak only.
    over = _mask(scene, [[0.09, 0.0, 0.099]], [[0.25, 0.0, 0.15]])
    assert over[:, 0].tolist() == [False, True]


def test_the_first_frame_of_an_open_hopper_is_tested_against_its_convex_hull():
    scene = make_hopper(num_particles=100)
    p = scene.params
    z = 0.03
    half = p["opening"] / 2 + z / math.tan(math.radians(p["alpha_deg"]))
    frame = np.array([[[0.0, 0.0, z], [half + 0.001, 0.0, z], [0.0, 0.0, -0.01]]])
    assert leaked_mask(frame, scene, np.array([0.0]))[0].tolist() == [False, True, False]
    assert not leaked_mask(frame, scene, np.array([0.0]), initial=False).any()


@pytest.mark.parametrize("seed", range(4))
def test_crossings_match_a_dense_loop_over_every_triangle(seed):
    """Random triangles on a static and a turning wall, random moves at every scale: the
    candidate search finds exactly the (move, triangle) crossings of the dense all-pairs loop."""
    rng = np.random.default_rng(seed)
    walls = []
    for name, motion in [
        ("fixed", WallMotion()),
        ("turning", WallMotion("rotation", axis=tuple(rng.normal(size=3)), omega=3.0)),
    ]:
        centres = rng.uniform(-0.1, 0.1, (40, 1, 3))
        size = rng.choice([0.005, 0.03, 0.1], (40, 1, 1))
        vertices = (centres + size * rng.normal(size=(40, 3, 3))).reshape(-1, 3)
        walls.append(Wall(name, vertices, np.arange(120).reshape(40, 3), motion))
    t0, t1 = 0.2, 0.23
    n = 3000
    start = rng.uniform(-0.15, 0.15, (n, 3))
    length = rng.choice([0.0005, 0.005, 0.05, 0.2], n)[:, None]
    end = start + length * rng.normal(size=(n, 3))
    start[:5] = np.nan  # never cross
    got = WallSet(walls).crossings(torch.from_numpy(start), torch.from_numpy(end), t0, t1)
    expected = np.zeros(n, bool)
    ok = np.isfinite(start).all(1)
    for wall in walls:
        rot0, shift0 = wall.motion.pose(t0)
        rot1, shift1 = wall.motion.pose(t1)
        q0 = torch.from_numpy((start[ok] - shift0) @ rot0)
        q1 = torch.from_numpy((end[ok] - shift1) @ rot1)
        for tri in torch.from_numpy(wall.triangles):
            hit = segment_triangle_crossings(q0, q1, tri.expand(len(q0), 3, 3)).crosses
            expected[np.flatnonzero(ok)[hit.numpy()]] = True
    assert 50 < expected.sum() < n - 50
    assert np.array_equal(got.numpy(), expected)
