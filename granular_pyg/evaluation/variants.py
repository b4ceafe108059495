"""Variants of a recorded trajectory that change nothing physically, and its bed held at rest.

- :func:`turned_trajectory`, :func:`subdivided_trajectory`: the same run turned about gravity,
  mirrored, shifted or with its walls re-meshed (positions, velocities, walls and their motion
  alike), for ``bench suite=invariance``;
- :func:`held_still`: the first frame of a run, with every wall present and still for ever,
  for ``bench suite=rest`` (a settled bed on a closed lid, a drum that does not turn).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from granular_pyg.errors import InputError
from granular_pyg.geometry import horizontal_frame
from granular_pyg.io import Trajectory
from granular_pyg.scenes import WallMotion
from granular_pyg.scenes.redescribe import subdivided_scene, turned_scene

__all__ = ["VARIANTS", "held_still", "subdivided_trajectory", "turned_trajectory", "variant"]

#: The variants of ``bench suite=invariance``: name -> (turn in degrees, mirror, re-meshings).
#: ``turn_random`` takes its angle from the suite's seed.
VARIANTS: dict[str, tuple[float | None, bool, int]] = {
    "original": (0.0, False, 0),
    "turn_45": (45.0, False, 0),
    "turn_90": (90.0, False, 0),
    "turn_random": (None, False, 0),
    "mirror": (0.0, True, 0),
    "remesh_x4": (0.0, False, 1),
    "remesh_x16": (0.0, False, 2),
}


def _need_scene(traj: Trajectory) -> None:
    if traj.scene is None:
        raise InputError("trajectory: has no Scene (walls); variants need one")


def turned_trajectory(traj: Trajectory, frame, shift=(0.0, 0.0, 0.0)) -> Trajectory:
    """``traj`` turned by ``frame`` (``[3, 3]``, fixing z) and shifted by ``shift`` (m)."""
    _need_scene(traj)
    q = np.asarray(frame, np.float64)
    shift = np.asarray(shift, np.float64)
    positions = (traj.positions.astype(np.float64) @ q.T + shift).astype(traj.positions.dtype)
    velocities = (traj.velocities.astype(np.float64) @ q.T).astype(traj.velocities.dtype)
    return dataclasses.replace(
        traj,
        positions=positions,
        velocities=velocities,
        scene=turned_scene(traj.scene, q, shift),
        metadata=dict(traj.metadata),
    )


def subdivided_trajectory(traj: Trajectory, times: int = 1) -> Trajectory:
    """``traj`` with every wall triangle split in four ``times`` times (the same surfaces)."""
    _need_scene(traj)
    return dataclasses.replace(
        traj, scene=subdivided_scene(traj.scene, times), metadata=dict(traj.metadata)
    )


def variant(traj: Trajectory, name: str, seed: int = 0) -> Trajectory:
    """The :data:`VARIANTS` entry ``name`` of ``traj`` (``turn_random``: an angle drawn from
    ``seed``)."""
    if name not in VARIANTS:
        raise InputError(f"variant: expected one of {list(VARIANTS)}, got {name!r}")
    angle, mirror, times = VARIANTS[name]
    if angle is None:
        angle = float(np.random.default_rng(seed).uniform(0.0, 360.0))
    out = traj
    if angle or mirror:
        out = turned_trajectory(out, horizontal_frame(angle, mirror).numpy())
    return subdivided_trajectory(out, times) if times else out


def held_still(traj: Trajectory, duration: float, frame: int = 0) -> Trajectory:
    """A settled bed held still: frame ``frame`` of ``traj`` (its present particles) repeated
    over ``duration`` (s) at the trajectory's frame spacing, every wall present throughout and
    never moving (the lid never removed, the drum never turning).

    A model rolled out over it starts from rest (all velocities zero) and should stay there.
    """
    _need_scene(traj)
    if not duration > 0:
        raise InputError(f"duration: expected a positive time (s), got {duration!r}")
    pos = traj.positions[frame]
    keep = np.isfinite(pos).all(1)
    if not keep.any():
        raise InputError(f"frame {frame}: no particle is present")
    count = round(duration / traj.frame_dt) + 1
    walls = [
        dataclasses.replace(w, motion=WallMotion(), removal_time=None) for w in traj.scene.walls
    ]
    scene = dataclasses.replace(traj.scene, walls=walls)
    positions = np.repeat(pos[keep][None], count, axis=0)
    return dataclasses.replace(
        traj,
        positions=positions,
        velocities=np.zeros_like(positions),
        radii=traj.radii[keep],
        ids=traj.ids[keep],
        times=traj.times[frame] + traj.frame_dt * np.arange(count),
        scene=scene,
        metadata=dict(traj.metadata) | {"held_still_from_frame": int(frame)},
    )
