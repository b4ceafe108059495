"""What the wall guard guarantees, as a property (issue 36, item 5): after
:meth:`WallSet.contain`, no move from a start inside the walls crosses a wall present at the
move's end, by the leak count's own crossing test (:meth:`WallSet.crossings`, test 1 of
``metrics.leaks``), also after the corrected ends are stored in float32 as a rollout stores
them; and every corrected end keeps at least ``2 * GUARD_SKIN * margin`` from the crossed
plane. Random moves of up to twice the equipment's size, into corners where two separate walls
meet (a square hopper made of four walls, as a user's import), and a rotating closed box.

What it does not promise: a particle that leaves through an opening (the open top) or ends
outside the simulation box is not stopped; the leak count counts that as test 2.
"""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from granular_pyg.scenes import Wall, WallSet
from granular_pyg.scenes.scene import WallMotion

A, B, H = 0.01, 0.05, 0.1  # square hopper: outlet half-width, top half-width, height (m)


def _square_hopper() -> WallSet:
    """Four separate sloped walls, two triangles each, meeting at the corners (open top and
    bottom)."""
    walls = []
    corners_low = [(-A, -A), (A, -A), (A, A), (-A, A)]
    corners_top = [(-B, -B), (B, -B), (B, B), (-B, B)]
    for k in range(4):
        (x0, y0), (x1, y1) = corners_low[k], corners_low[(k + 1) % 4]
        (u0, v0), (u1, v1) = corners_top[k], corners_top[(k + 1) % 4]
        vertices = np.array([[x0, y0, 0.0], [x1, y1, 0.0], [u1, v1, H], [u0, v0, H]])
        walls.append(Wall(f"side{k}", vertices, np.array([[0, 1, 2], [0, 2, 3]])))
    return WallSet(walls)


def _box(rotating: bool) -> WallSet:
    """A closed 10 cm box (12 triangles), turning about y at 2 rad/s when ``rotating``."""
    v = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)])
    faces = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    motion = WallMotion("rotation", omega=2.0) if rotating else WallMotion()
    return WallSet([Wall("box", v, faces, motion)])


def _inside_hopper(rng: np.random.Generator, n: int) -> np.ndarray:
    z = rng.uniform(0.002, H - 0.002, n)
    half = A + (B - A) * z / H
    xy = rng.uniform(-1.0, 1.0, (n, 2)) * (half[:, None] - 1e-4)
    return np.column_stack([xy, z])


def _check(walls: WallSet, start: np.ndarray, step: np.ndarray, margin: np.ndarray, t0: float):
    t1 = t0 + 0.01
    p0 = torch.from_numpy(start).float()  # a rollout's positions are float32
    p1 = (p0.double() + torch.from_numpy(step)).float()
    m = torch.from_numpy(margin)
    assert not bool(walls.crossings(p0, p0, t0, t0).any())
    end, corrected = walls.contain(p0, p1, t0, t1, m, radius=0.0075)
    assert end.dtype == torch.float32
    crossed = walls.crossings(p0, end, t0, t1)
    assert not bool(crossed.any()), f"{int(crossed.sum())} guarded moves cross a wall"
    return end, corrected


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.002, 0.2))
def test_no_guarded_move_crosses_a_wall_of_a_square_hopper_made_of_four_walls(seed, reach):
    rng = np.random.default_rng(seed)
    n = 200
    start = _inside_hopper(rng, n)
    step = rng.normal(size=(n, 3)) * reach
    step[: n // 3] = np.sign(start[: n // 3]) * reach * np.array([1.0, 1.0, -0.3])  # corners
    margin = rng.uniform(2e-4, 1.5e-3, n)
    _, corrected = _check(_square_hopper(), start, step, margin, 0.0)
    assert corrected > 0 or reach < 0.005


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.001, 0.2), st.booleans())
def test_no_guarded_move_crosses_the_walls_of_a_closed_box(seed, reach, rotating):
    rng = np.random.default_rng(seed)
    n = 200
    walls = _box(rotating)
    t0 = float(rng.uniform(0.0, 1.0))
    rot0, shift0 = walls.walls[0].motion.pose(t0)
    start = rng.uniform(-0.0499, 0.0499, (n, 3)) @ rot0.T + shift0  # inside the box at t0
    step = rng.normal(size=(n, 3)) * reach
    margin = rng.uniform(2e-4, 1.5e-3, n)
    end, _ = _check(walls, start, step, margin, t0)
    # the box is closed: every guarded end is inside it (posed at t1)
    rot, shift = walls.walls[0].motion.pose(t0 + 0.01)
    local = (end.double().numpy() - shift) @ rot
    assert np.all(np.abs(local) < 0.05), np.abs(local).max()


def test_a_particle_that_leaves_through_the_open_top_is_not_stopped():
    """The guard stops crossings, not exits through openings: a move straight up out of the
    hopper's open top is left as it is (the leak count counts it when it leaves the box)."""
    walls = _square_hopper()
    start = torch.tensor([[0.0, 0.0, 0.09]], dtype=torch.float32)
    end = torch.tensor([[0.0, 0.0, 0.2]], dtype=torch.float32)
    kept, corrected = walls.contain(start, end, 0.0, 0.01, 1e-3, radius=0.0075)
    assert corrected == 0 and torch.equal(kept, end)


def test_a_guarded_rollout_leaks_nothing_by_the_evaluation_count():
    """Why a guarded rollout once leaked a particle by the project's count: the count included
    the moves between the rollout's initial states, which are LIGGGHTS's frames ``k`` apart
    (``k = 16`` for ``pretrained:fast_hopper``: 40 ms), whose straight chords cut the corner of
    the hopper's outlet. The guard never sees those (they are not predictions); the evaluation
    now counts leaks from the last initial state on, for prediction and truth alike."""
    from granular_pyg.checkpoint import load_simulator
    from granular_pyg.evaluation.pair import evaluate_pair
    from granular_pyg.inference import rollout_trajectory
    from granular_pyg.io import read_trajectory
    from granular_pyg.samples import sample_files

    sim, _ = load_simulator("pretrained:fast_hopper")
    truth = read_trajectory(sample_files("hopper", "test")[0])
    pred = rollout_trajectory(sim, truth, progress=False, wall_guard=True)
    pos = torch.from_numpy(pred.positions.astype(np.float64))
    chords = WallSet(pred.scene).crossings(pos[3], pos[4], *map(float, pred.times[3:5]))
    assert int(chords.sum()) == 1  # a chord between two initial (truth) states crosses
    scalars = evaluate_pair(truth, pred).scalars
    assert scalars["leaked_particles"] == 0
