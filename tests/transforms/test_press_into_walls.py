"""PressIntoWalls: near-wall training inputs moved towards the wall, never through it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch_geometric.data import Data

from granular_pyg.errors import InputError
from granular_pyg.scenes import Wall, WallSet, make_drum
from granular_pyg.transforms import PressIntoWalls
from granular_pyg.transforms.press_into_walls import MAX_PRESS_FRACTION

# A floor at z = 0: two triangles over [-1, 1]^2 (m).
FLOOR = Wall(
    "floor",
    np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64),
    np.array([[0, 1, 2], [0, 2, 3]]),
)


def _history(heights: list[float], steps: int = 5) -> torch.Tensor:
    """``[N, steps + 1, 3]`` particles at x = y = 0.1 falling 0.1 mm per frame onto the floor,
    their last positions at ``heights`` (m)."""
    z = torch.tensor(heights, dtype=torch.float64)[:, None] + 1e-4 * torch.arange(steps, -1, -1)
    return torch.stack([torch.full_like(z, 0.1), torch.full_like(z, 0.1), z], dim=2)


def _press(seq, walls, depth=5e-4, reach=2e-3, fraction=1.0, seed=0, time=0.0, approach=0.0):
    generator = torch.Generator().manual_seed(seed)
    press = PressIntoWalls(depth, reach, fraction, approach, generator)
    return press(Data(pos_seq=seq.clone(), walls=walls, time=time))


def test_a_particle_on_the_floor_moves_straight_down_with_its_history():
    seq = _history([1e-3, 1.5e-3, 3e-3])  # the last is beyond reach
    data = _press(seq, WallSet([FLOOR]))
    moved = data.pos_seq - seq
    # Only z changes, by the same amount in every frame (the velocities are LIGGGHTS's).
    torch.testing.assert_close(moved[..., :2], torch.zeros_like(moved[..., :2]), rtol=0, atol=1e-15)
    torch.testing.assert_close(moved[..., 2], moved[:, -1:, 2].expand_as(moved[..., 2]))
    torch.testing.assert_close(-moved[:, -1, 2], data.pressed)
    assert 0 < data.pressed[0] <= 5e-4 and 0 < data.pressed[1] <= 5e-4
    assert data.pressed[2] == 0  # 3 mm from the floor, reach 2 mm
    assert torch.equal(data.pos, data.pos_seq[:, -1])


def test_a_press_stops_short_of_the_plane():
    """A centre 0.1 mm above the floor moves at most 90% of that, however deep the press."""
    seq = _history([1e-4] * 200)
    data = _press(seq, WallSet([FLOOR]), depth=1e-3)
    assert float(data.pressed.max()) <= MAX_PRESS_FRACTION * 1e-4 + 1e-12
    assert float(data.pos_seq[:, -1, 2].min()) > 0


def test_an_approach_adds_a_velocity_into_the_wall_and_keeps_the_current_press():
    """With ``approach``, frame j moves (H - j) * a further back from the floor: the particle
    comes down a faster (per frame), and its current position is pressed as before."""
    seq = _history([1e-3] * 300)
    walls = WallSet([FLOOR])
    plain = _press(seq, walls, seed=2)
    data = _press(seq, walls, seed=2, approach=4e-4)
    torch.testing.assert_close(data.pos_seq[:, -1], plain.pos_seq[:, -1])
    velocity = torch.diff(data.pos_seq[..., 2], dim=1)  # m per frame, [N, H]
    torch.testing.assert_close(velocity, torch.diff(seq[..., 2], dim=1) - data.approach[:, None])
    assert float(data.approach.min()) > 0 and float(data.approach.max()) <= 4e-4
    assert float(data.approach.mean()) == pytest.approx(2e-4, rel=0.1)


def test_fraction_sets_how_many_candidates_are_pressed():
    seq = _history([1e-3] * 4000)
    pressed = _press(seq, WallSet([FLOOR]), fraction=0.25).pressed
    assert float((pressed > 0).float().mean()) == pytest.approx(0.25, abs=0.03)
    # U(0, depth) among the pressed: mean depth / 2.
    assert float(pressed[pressed > 0].mean()) == pytest.approx(2.5e-4, rel=0.05)


def test_the_same_generator_seed_gives_the_same_presses():
    seq = _history([1e-3] * 50)
    walls = WallSet([FLOOR])
    assert torch.equal(_press(seq, walls, seed=4).pos_seq, _press(seq, walls, seed=4).pos_seq)
    assert not torch.equal(_press(seq, walls, seed=4).pos_seq, _press(seq, walls, seed=5).pos_seq)


def test_no_wall_within_reach_changes_nothing():
    seq = _history([0.01, 0.02])
    data = _press(seq, WallSet([FLOOR]))
    assert torch.equal(data.pos_seq, seq)
    assert torch.equal(data.pressed, torch.zeros(2, dtype=seq.dtype))


def test_drum_presses_move_towards_the_nearest_wall_and_stay_inside_brute_force():
    """Random centres in the drum: each pressed one moves towards the closest point of its
    nearest triangle (found here by brute force over every triangle) and stays inside."""
    scene = make_drum()
    walls = WallSet(scene)
    p = scene.params
    rng = np.random.default_rng(0)
    n = 3000
    r = p["drum_radius"] * np.sqrt(rng.uniform(0.8, 1.0, n))
    phi = rng.uniform(0, 2 * math.pi, n)
    y = rng.uniform(-0.5, 0.5, n) * p["length"]
    last = torch.from_numpy(np.stack([r * np.cos(phi), y, r * np.sin(phi)], 1))
    seq = last[:, None, :].repeat(1, 6, 1)
    time = 0.3  # the drum turns: the walls' pose at this time
    data = _press(seq, walls, depth=1e-3, reach=3e-3, time=time)
    rows = (data.pressed > 0).nonzero().squeeze(1)
    assert rows.numel() > 100
    every = walls.contacts(last, 1.0, time)  # all pairs: brute force over the triangles
    dist = torch.linalg.vector_norm(every.closest - last[every.point_idx], dim=1)
    for i in rows[:200].tolist():
        mine = every.point_idx == i
        j = int(dist[mine].argmin())
        toward = every.closest[mine][j] - last[i]
        step = data.pos_seq[i, -1] - last[i]
        torch.testing.assert_close(step, toward / dist[mine][j] * data.pressed[i])
        assert float(data.pressed[i]) <= MAX_PRESS_FRACTION * float(dist[mine][j]) + 1e-12
    # Nobody pressed out of the shell or the caps.
    end = data.pos_seq[:, -1].numpy()
    assert (np.hypot(end[:, 0], end[:, 2]) < p["drum_radius"]).all()
    assert (np.abs(end[:, 1]) < p["length"] / 2).all()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"depth": 0.0, "reach": 1e-3}, "depth"),
        ({"depth": math.nan, "reach": 1e-3}, "depth"),
        ({"depth": 1e-3, "reach": -1.0}, "reach"),
        ({"depth": 1e-3, "reach": 1e-3, "fraction": 0.0}, "fraction"),
        ({"depth": 1e-3, "reach": 1e-3, "approach": -1e-3}, "approach"),
    ],
)
def test_bad_settings_are_named(kwargs, match):
    with pytest.raises(InputError, match=match):
        PressIntoWalls(**kwargs)


def test_the_data_module_checks_its_press_settings():
    from granular_pyg.training import TrajectoryDataModule

    with pytest.raises(InputError, match="reach"):
        TrajectoryDataModule(sample="hopper", wall_press=1e-3, wall_press_reach=0.0)
    with pytest.raises(InputError, match="depth"):
        TrajectoryDataModule(sample="hopper", wall_press=-1e-3, wall_press_reach=2e-3)
    module = TrajectoryDataModule(sample="hopper", wall_press=1e-3, wall_press_reach=2.5e-3)
    assert module.press == (1e-3, 2.5e-3, 0.5, 0.0)
    assert TrajectoryDataModule(sample="hopper").press is None


def test_a_pressed_batch_asks_the_pressed_particles_to_move_back_out():
    """Through the training collate: the inputs near the walls move, the rest and the target do
    not, so the target acceleration of a pressed particle points away from its wall by the
    press over dt^2."""
    from hydra.utils import instantiate

    from granular_pyg.config import compose
    from granular_pyg.data.windows import WindowDataset
    from granular_pyg.io import read_trajectory
    from granular_pyg.samples import sample_files
    from granular_pyg.training.data_module import _Collate

    hopper = read_trajectory(sample_files("hopper", "train")[0])
    sim = instantiate(compose("train", ["model.latent=16"]).model)
    step = 2
    sim.dt.fill_(step * hopper.frame_dt)
    window = WindowDataset([hopper], 5, step)[40]
    plain = _Collate(sim, 0.0, True, 0)([window])
    pressed = _Collate(sim, 0.0, True, 0, press=(1e-3, 2.5e-3, 1.0))([window])
    moved = pressed.noisy_pos_seqs[0] - window.pos_seq  # [N, H + 1, 3]
    depth = torch.linalg.vector_norm(moved[:, -1], dim=1)
    rows = depth > 0
    assert 10 < int(rows.sum()) < len(depth)
    torch.testing.assert_close(moved, moved[:, -1:].expand_as(moved))  # same in every frame
    near = WallSet(hopper.scene).contacts(window.pos_seq[:, -1], 2.5e-3, window.time)
    assert set(rows.nonzero().squeeze(1).tolist()) <= set(near.point_idx.tolist())
    # The target acceleration changes by the press over dt^2, against its direction.
    extra = (pressed.y - plain.y).double() * sim.acc_std.double()  # m/s^2
    dt = float(sim.dt)
    torch.testing.assert_close(extra[rows], -moved[rows, -1].double() / dt**2, rtol=1e-4, atol=1e-3)
    assert torch.equal(extra[~rows], torch.zeros_like(extra[~rows]))
