"""``data.mask_beyond_reach``: in a step that removes the lid or follows its removal, only
the particles the model's message passing can reach from it keep their target; every other
window is untouched."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
import trimesh

from granular_pyg.data.windows import WindowDataset
from granular_pyg.evaluation.variants import turned_trajectory
from granular_pyg.geometry import horizontal_frame
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.data_module import _Collate
from granular_pyg.training.objectives import Unrolled, masked_mse
from granular_pyg.training.reach_mask import within_reach_of_events


def _model() -> LearnedSimulator:
    torch.manual_seed(0)
    sim = LearnedSimulator(Processor(latent=16, num_steps=2), radius=0.0075, latent=16, dt=0.0025)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    return sim.eval()


def test_only_particles_within_reach_of_the_removed_lid_keep_their_target():
    sim = _model()
    assert math.isclose(sim.reach, 2 * 0.0075)  # two message-passing steps of the cut-off
    data = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1)
    lid = data.trajs[0].scene.wall("lid")
    mesh = trimesh.Trimesh(lid.vertices_at(0.0), lid.faces, process=False)
    masked, plain = _Collate(sim, 0.0, 0, mask_beyond_reach=True), _Collate(sim, 0.0, 0)
    events = 0
    for i in range(len(data)):
        w = data[i]
        if w.time > 0.04:  # the lid goes at 0.02 s; later windows are like the ones before
            continue
        y, y_plain = masked([w]).y, plain([w]).y
        dt = float(sim.dt)
        if not w.time - dt - 1e-9 <= lid.removal_time <= w.time + dt + 1e-9:
            assert torch.equal(y, y_plain), w.time  # no event: every target kept
            continue
        events += 1
        _, distance, _ = trimesh.proximity.closest_point(mesh, w.pos_seq[:, -1].double().numpy())
        kept = torch.isfinite(y).all(dim=1).numpy()
        np.testing.assert_array_equal(kept, distance < sim.reach)
        assert 0 < kept.sum() < len(kept)
        torch.testing.assert_close(y[kept], y_plain[kept], rtol=0, atol=0)
        loss = masked_mse(torch.zeros_like(y), y)
        assert torch.isfinite(loss) and loss == (y_plain[kept] ** 2).mean()
    assert events == 3  # the steps ending at, starting from and one after the removal


def _drum_that_reverses_and_stops(traj):
    """The sample drum's run with its motion given a reversal and a stop (more events)."""
    walls = [
        dataclasses.replace(
            w, motion=dataclasses.replace(w.motion, reverse_times=(0.4,), stop_time=0.7)
        )
        for w in traj.scene.walls
    ]
    return dataclasses.replace(traj, scene=dataclasses.replace(traj.scene, walls=walls))


def test_the_mask_is_the_same_for_the_scene_turned_mirrored_or_shifted():
    """The mask depends on distances to the walls and on event times only: the sample hopper
    (lid removed) and drum (turning starts, reverses, stops) turned about gravity, mirrored
    and shifted keep exactly the particles they kept before, at every step."""
    frames = [horizontal_frame(37.0), horizontal_frame(90.0, mirror=True)]
    for scene_name, num_steps in (("hopper", 2), ("drum", 1)):
        torch.manual_seed(0)
        sim = LearnedSimulator(
            Processor(latent=16, num_steps=num_steps), radius=0.0075, latent=16, dt=0.0025
        )
        traj = read_trajectory(sample_files(scene_name)[0])
        if scene_name == "drum":
            traj = _drum_that_reverses_and_stops(traj)
        variants = [turned_trajectory(traj, q.numpy(), shift=(0.3, -0.2, 0.05)) for q in frames]
        walls = [WallSet(t.scene) for t in (traj, *variants)]
        partial = 0
        for frame, time in enumerate(traj.times):
            masks = []
            for t, w in zip((traj, *variants), walls, strict=True):
                last = torch.from_numpy(t.positions[frame]).double()
                masks.append(within_reach_of_events(w, last, float(time), sim.dt, sim.reach))
            for m in masks[1:]:
                assert torch.equal(m, masks[0]), (scene_name, float(time))
            partial += bool(0 < masks[0].sum() < len(masks[0]))
        assert partial >= 2, scene_name  # the events leave part of the bed out


def _assert_only_the_unmasked_loss_moves(sim, objective, w, v) -> None:
    """``objective``'s loss on windows ``w`` and ``v`` (``w`` with some recorded frames moved):
    the same with ``mask_beyond_reach``, different without it."""
    losses = {}
    for mask in (True, False):
        collate = _Collate(sim, 0.0, 0, mask_beyond_reach=mask)
        with torch.no_grad():
            losses[mask] = [
                float(objective.loss(sim, collate([x]), torch.Generator())) for x in (w, v)
            ]
    assert losses[True][0] == losses[True][1]
    assert losses[False][0] != losses[False][1]


def test_the_unrolled_loss_does_not_depend_on_the_targets_it_masks():
    """Unrolled runs near the lid's removal: with the mask, moving the recorded future of the
    particles beyond reach of the lid leaves the loss unchanged; without it, it does not."""
    sim = _model()
    data = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1, extra_steps=2)
    lid = data.trajs[0].scene.wall("lid")
    (w,) = [data[i] for i in range(len(data)) if abs(data[i].time - lid.removal_time) < 1e-9]
    far = ~within_reach_of_events(w.walls, w.pos_seq[:, -1].double(), w.time, sim.dt, sim.reach)
    assert 0 < far.sum() < len(far)
    moved = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1, extra_steps=2)
    (v,) = [moved[i] for i in range(len(moved)) if abs(moved[i].time - lid.removal_time) < 1e-9]
    v.target_pos[far] += torch.tensor([0.0, 0.0, -1e-3])
    _assert_only_the_unmasked_loss_moves(sim, Unrolled(steps=2, share=1.0), w, v)


def test_an_unrolled_run_ends_at_the_step_that_masks_particles():
    """A run that starts two steps before the lid goes: its second step masks the bed beyond
    reach and ends the run, so the recorded frames after it do not count; without the mask
    they do (the bed the model kept at rest would be asked to catch up with the fall)."""
    sim = _model()
    dt = float(sim.dt)
    lid = sample_files("hopper")[:1]
    data = WindowDataset(lid, history=5, frames_per_step=1, extra_steps=2)
    removal = data.trajs[0].scene.wall("lid").removal_time
    index = next(i for i in range(len(data)) if abs(data[i].time - (removal - 2 * dt)) < 1e-9)
    w, v = data[index], WindowDataset(lid, history=5, frames_per_step=1, extra_steps=2)[index]
    v.future[:, 1] += torch.tensor([0.0, 0.0, -1e-3])  # the third step's target, every particle
    _assert_only_the_unmasked_loss_moves(sim, Unrolled(steps=3, share=1.0), w, v)
