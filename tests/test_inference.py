"""Rollouts over a Scene: checkpoint loading, frames and times, moving walls, lid, outflow."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.geometry import closest_point_on_triangles
from granular_pyg.inference import (
    frames_per_step,
    load_simulator,
    matching_frames,
    rollout_trajectory,
)
from granular_pyg.io import read_trajectory
from granular_pyg.metrics import leaked_particles
from granular_pyg.rollout import rollout
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.train import train


@pytest.fixture(scope="module")
def sim():
    torch.manual_seed(0)
    model = instantiate(compose("train", ["model.latent=16"]).model).eval()
    model.dt.fill_(2 * 2.5e-3)  # time-step multiple k = 2 on the 2.5 ms samples
    return model


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


@pytest.fixture(scope="module")
def drum():
    return read_trajectory(sample_files("drum", "test")[0])


def test_rollout_has_the_initial_states_then_one_frame_per_learned_step(sim, hopper):
    pred = rollout_trajectory(sim, hopper, steps=4, start_frame=10, progress=False)
    k = frames_per_step(sim, hopper.frame_dt)
    assert k == 2
    assert pred.num_frames == sim.history + 1 + 4
    frames = matching_frames(hopper, pred)
    np.testing.assert_array_equal(frames, np.arange(10, 10 + 2 * pred.num_frames, 2))
    np.testing.assert_array_equal(pred.positions[:6], hopper.positions[frames[:6]])
    assert pred.metadata["steps"] == 4 and pred.metadata["frames_per_step"] == 2
    assert np.isfinite(pred.positions[6:][hopper.present[frames[6:]]]).all()
    # velocities of predicted frames are backward differences over one learned step
    np.testing.assert_allclose(
        pred.velocities[7], (pred.positions[7] - pred.positions[6]) / 5e-3, rtol=1e-5, atol=1e-6
    )


def test_rollout_defaults_to_the_end_of_the_trajectory(sim, hopper):
    short = dataclasses.replace(
        hopper,
        positions=hopper.positions[:20],
        velocities=hopper.velocities[:20],
        times=hopper.times[:20],
    )
    pred = rollout_trajectory(sim, short, progress=False)
    assert pred.metadata["steps"] == (20 - 1 - 10) // 2
    assert pred.times[-1] <= short.times[-1] + 1e-12


def test_rollout_errors_name_the_fix(sim, hopper):
    with pytest.raises(InputError, match="start_frame"):
        rollout_trajectory(sim, hopper, steps=1, start_frame=hopper.num_frames - 3)
    odd = instantiate(compose("train", ["model.latent=16"]).model)
    odd.dt.fill_(1.7e-3)
    with pytest.raises(InputError, match="not a multiple"):
        rollout_trajectory(odd, hopper, steps=1)
    shifted = dataclasses.replace(hopper, times=hopper.times + 1e-4)
    with pytest.raises(InputError, match="not a frame of the ground truth"):
        matching_frames(hopper, shifted)


def test_rotating_walls_put_the_wall_nodes_where_the_scene_pose_says(sim, drum):
    """At a late time the drum has turned; every wall node of the graph is the closest point of
    its particle on the triangle posed by ``Wall.vertices_at(t)`` (brute force)."""
    t = float(drum.times[-1])
    wall = drum.scene.walls[0]
    assert wall.motion.kind == "rotation" and wall.motion.angle(t) != 0.0
    pos = torch.from_numpy(drum.positions[-1]).double()
    contacts = WallSet(drum.scene).contacts(pos, sim.radius, t)
    assert len(contacts.point_idx) > 0
    posed = torch.from_numpy(wall.vertices_at(t))[torch.from_numpy(wall.faces)]
    expect, sq = closest_point_on_triangles(pos[contacts.point_idx], posed[contacts.tri_idx])
    torch.testing.assert_close(contacts.closest, expect, rtol=0, atol=1e-12)
    assert bool((sq < sim.radius**2).all())
    at_rest = torch.from_numpy(wall.vertices)[torch.from_numpy(wall.faces)]
    moved = (posed - at_rest).abs().max()
    assert moved > 1e-3  # the pose really differs from the mesh frame


def test_the_hopper_lid_is_a_wall_until_t_open_only(hopper):
    lid = hopper.scene.wall("lid")
    walls = WallSet(hopper.scene)
    x = np.array([[0.0, 0.0, 0.001]])  # just above the middle of the outlet
    before = walls.contacts(torch.from_numpy(x), 0.003, lid.removal_time - 1e-3)
    after = walls.contacts(torch.from_numpy(x), 0.003, lid.removal_time + 1e-3)
    names = [w.name for w in walls.walls]
    lid_first = walls.offsets[names.index("lid")]
    lid_tris = range(lid_first, lid_first + len(lid.faces))
    assert any(int(t) in lid_tris for t in before.tri_idx)
    assert not any(int(t) in lid_tris for t in after.tri_idx)


def test_particles_below_the_outflow_leave_the_rollout(sim, hopper):
    """Particle 0 falls 1 mm per learned step and is 0.5 mm above the outflow at the last
    initial state: the first predicted step takes it out (it becomes NaN and stays NaN)."""
    pos = hopper.positions.copy()
    frames = np.arange(hopper.num_frames)
    pos[:, 0] = 0.0
    pos[:, 0, 2] = hopper.scene.outflow_z + 0.0005 * (21 - frames)
    falling = dataclasses.replace(hopper, positions=pos)
    pred = rollout_trajectory(sim, falling, steps=3, start_frame=10, progress=False)
    assert np.isfinite(pred.positions[5, 0]).all()
    assert np.isnan(pred.positions[6:, 0]).all()
    assert np.isfinite(pred.positions[6:, 1:][:, hopper.present[20, 1:]]).all()


def test_the_wall_guard_keeps_particles_thrown_at_the_walls_inside(sim, hopper):
    """Every particle is given 0.4 m/s away from the hopper's centre plane over its initial
    states: an untrained model carries many through the V walls, the guard none."""
    k, start = 2, 10
    last = start + 5 * k  # the last initial state, left where it is
    frames = np.arange(hopper.num_frames)[:, None]
    pos = hopper.positions.copy()
    outward = np.sign(pos[last, :, 0])  # -1 / +1: towards the nearer V wall
    pos[..., 0] += 0.4 * outward * (frames - last) * hopper.frame_dt
    thrown = dataclasses.replace(hopper, positions=pos)
    free = rollout_trajectory(sim, thrown, steps=6, start_frame=start, progress=False)
    held = rollout_trajectory(
        sim, thrown, steps=6, start_frame=start, progress=False, wall_guard=True
    )
    scene = hopper.scene
    leaked_free = leaked_particles(free.positions[6:], scene, free.times[6:])
    assert leaked_free > 50
    assert leaked_particles(held.positions[6:], scene, held.times[6:]) == 0
    assert held.metadata["wall_guard"] is True
    assert held.metadata["wall_guard_corrections"] >= leaked_free
    assert free.metadata["wall_guard"] is False


def test_load_simulator_rejects_files_that_are_not_checkpoints(tmp_path):
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable checkpoint"):
        load_simulator(bad)
    torch.save({"state_dict": {}}, tmp_path / "plain.ckpt")
    with pytest.raises(InputError, match="not a granular_pyg training checkpoint"):
        load_simulator(tmp_path / "plain.ckpt")
    with pytest.raises(InputError, match="no checkpoint at"):
        load_simulator(tmp_path / "missing.ckpt")


@pytest.mark.slow
def test_rollout_command_writes_a_trajectory_of_the_trained_model(tmp_path, hopper):
    cfg = compose(
        "train",
        [
            "model.latent=16",
            "data.batch_size=1",
            "trainer.enable_progress_bar=false",
            "trainer.fast_dev_run=false",
            "trainer.max_steps=1",
            "data.train_samples_per_epoch=1",
            "data.val_samples=1",
            "rollout_validation.every_n_epochs=1000",
        ],
    )
    train(cfg, tmp_path / "run")
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    sim, config = load_simulator(ckpt)
    assert config["model"]["latent"] == 16 and not sim.training
    out = tmp_path / "pred.h5"
    pred, path = rollout(
        compose("rollout", [f"ckpt={ckpt}", "steps=3", f"out={out}", "progress=false"])
    )
    assert path == out
    again = read_trajectory(out)
    assert again.num_frames == 6 + 3
    np.testing.assert_array_equal(again.positions, pred.positions)
    assert again.metadata["truth_file"].endswith("traj_0003.h5")  # the test split by default


def test_processor_name_of_every_preset():
    from granular_pyg.checkpoint.model import processor_name
    from granular_pyg.config import compose

    names = {}
    for preset in ("bgnn", "gns", "attention", "equivariant"):
        cfg = compose("train", [f"model/processor={preset}"])
        names[preset] = processor_name(OmegaConf.to_container(cfg.model, resolve=True))
    assert names == {
        "bgnn": "interaction",
        "gns": "interaction",
        "attention": "attention",
        "equivariant": "equivariant",
    }
