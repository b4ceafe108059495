"""Using a trained model: load it from a checkpoint (:mod:`granular_pyg.checkpoint`, which owns
reading it) and roll it out over a Trajectory's Scene.

A rollout starts from the first ``H + 1`` ground-truth states (every ``k``-th frame, ``k`` the
time-step multiple the model was trained with), then feeds its own predictions back. The walls
follow the Scene (the drum rotates, the hopper's lid is removed at ``t_open``) and particles
that fall below the Scene's ``outflow_z`` leave, exactly as in LIGGGHTS. The result is a
:class:`~granular_pyg.io.Trajectory` like the ground truth, with one frame per learned step, so
every metric, plot and export takes both.
"""

from __future__ import annotations

import dataclasses
import os
import sys

import numpy as np
import torch

from granular_pyg.checkpoint import (
    load_simulator,
    load_weights,
    outside_training,
    read_checkpoint,
    whole_multiple,
)
from granular_pyg.errors import InputError, NonFiniteError, flag, positive_number, whole_number
from granular_pyg.io import Trajectory
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator, ParticleProps, WallGuard

__all__ = [
    "available_steps",
    "check_inside_scene",
    "frames_per_step",
    "initial_frames",
    "load_simulator",
    "load_weights",
    "matching_frames",
    "outside_scene",
    "read_checkpoint",
    "rollout_trajectory",
    "warn_outside_training",
]


def warn_outside_training(config: dict, truth: Trajectory, name: str) -> list[str]:
    """Print one ``warning:`` line (standard error) per property of ``truth`` outside the
    model's training data (its card), naming the trajectory ``name``; returns the messages."""
    found = outside_training(config.get("model_card"), truth)
    for message in found:
        print(f"warning: {name}: {message}; the prediction may be poor", file=sys.stderr)
    return found


def outside_scene(truth: Trajectory, frame: int) -> np.ndarray:
    """``[N]`` bool: particles of ``truth``'s frame ``frame`` (present ones only) whose centre
    lies outside the Scene: outside its simulation box (the outflow floor excepted), or more
    than a particle diameter outside the walls present then (their closed surface, or the
    convex hull of walls that enclose a volume; below the walls' lowest point of a scene with an
    outflow counts as inside: falling towards it).

    A learned rollout of such particles has no wall near them: they fall freely, and nothing
    they do says anything of the equipment.
    """
    from granular_pyg.scenes.containment import (
        inside_closed_surface,
        inside_convex_hull,
        is_closed_surface,
        walls_at,
    )

    scene = truth.scene
    pos = np.asarray(truth.positions[frame], np.float64)
    present = np.isfinite(pos).all(1)
    out = np.zeros(len(pos), bool)
    if scene is None or not present.any():
        return out
    p = pos[present]
    lo, hi = np.asarray(scene.domain_lo), np.asarray(scene.domain_hi)
    below = p < lo
    if scene.outflow_z is not None:
        below[:, 2] = False
    outside = (below | (p > hi)).any(1)
    triangles, _ = walls_at(scene, float(truth.times[frame]))
    if len(triangles):
        slack = 2.0 * float(np.max(truth.radii)) if truth.num_particles else 0.0
        if is_closed_surface(triangles):
            inner = inside_closed_surface(p, triangles)
        else:
            inner = inside_convex_hull(p, triangles.reshape(-1, 3), tol=-slack)
            if not inside_convex_hull(
                triangles.reshape(-1, 3).mean(0, keepdims=True), triangles.reshape(-1, 3)
            ).any():
                inner[:] = True  # walls that enclose no volume (a plate): nothing to test
        if scene.outflow_z is not None:
            inner |= p[:, 2] < triangles[..., 2].min()
        outside |= ~inner
    out[present] = outside
    return out


def check_inside_scene(truth: Trajectory, frame: int, name: str = "trajectory") -> int:
    """Refuse a rollout whose every particle starts outside the Scene (:func:`outside_scene`);
    print one ``warning:`` line when some do. Returns how many are outside.

    Raises:
        InputError: naming ``name``: every present particle is outside the walls or the box.
    """
    outside = outside_scene(truth, frame)
    count, present = int(outside.sum()), int(np.isfinite(truth.positions[frame]).all(1).sum())
    if count and count == present:
        raise InputError(
            f"{name}: all {count} particles start outside the walls or the simulation box of "
            "its Scene (a rollout would see no wall); check that the walls and the particles "
            "share one frame of reference and units (metres)"
        )
    if count:
        print(
            f"warning: {name}: {count} of {present} particles start outside the walls or the "
            "simulation box; they will not meet a wall",
            file=sys.stderr,
        )
    return count


def frames_per_step(sim: LearnedSimulator, frame_dt: float) -> int:
    """Saved frames per learned step: ``sim.dt / frame_dt``, which must be a whole number."""
    k = whole_multiple(float(sim.dt), frame_dt)
    if k is None:
        raise InputError(
            f"the model's step dt = {float(sim.dt):g} s is not a multiple of the trajectory's "
            f"frame spacing {frame_dt:g} s; roll out on data recorded every dt / k seconds"
        )
    return k


def initial_frames(
    sim: LearnedSimulator, truth: Trajectory, start_frame: int = 0
) -> tuple[int, np.ndarray]:
    """Where a rollout of ``sim`` over ``truth`` starts.

    Returns:
        ``(k, frames)``: saved frames per learned step and the ``[H + 1]`` indices of the
        ground-truth frames that are the initial states, every ``k``-th from ``start_frame``.

    Raises:
        InputError: no Scene (walls), uneven frame spacing, a frame spacing the model's step
            is not a multiple of, or too few frames.
    """
    if truth.scene is None:
        raise InputError("truth: a rollout needs the trajectory's Scene (walls); it has none")
    if truth.num_particles == 0:
        raise InputError("truth: the trajectory has no particles; there is nothing to roll out")
    truth.check_even_spacing()
    k = frames_per_step(sim, truth.frame_dt)
    frames = np.arange(start_frame, start_frame + (sim.history + 1) * k, k)
    if start_frame < 0 or frames[-1] >= truth.num_frames:
        raise InputError(
            f"start_frame: {start_frame} leaves fewer than {sim.history + 1} initial frames "
            f"(every {k}) in a trajectory of {truth.num_frames} frames"
        )
    return k, frames


def available_steps(sim: LearnedSimulator, truth: Trajectory, start_frame: int = 0) -> int:
    """Learned steps ``truth`` has ground-truth frames for after the initial states of a rollout
    of ``sim`` from ``start_frame`` (:func:`initial_frames`; its errors)."""
    k, initial = initial_frames(sim, truth, start_frame)
    return int((truth.num_frames - 1 - initial[-1]) // k)


def rollout_trajectory(
    sim: LearnedSimulator,
    truth: Trajectory,
    steps: int | None = None,
    start_frame: int = 0,
    progress: bool = True,
    dtype: torch.dtype = torch.float32,
    skin: float | None = None,
    wall_guard: bool = False,
    stop_when_empty: bool = False,
    precision: str = "32",
    name: str = "truth",
) -> Trajectory:
    """Roll ``sim`` out over ``truth``'s Scene from its ground-truth initial states.

    Args:
        sim: a trained simulator.
        truth: the ground truth; its Scene gives walls, their motion and the outflow.
        steps: learned steps to predict; None: as many as ``truth`` has frames for.
        start_frame: the frame of the oldest initial state.
        progress: show a progress bar.
        dtype: position dtype of the rollout (float32, or float64 for precision studies).
        skin: Verlet skin (m) to reuse the particle graph between steps (the same edges, fewer
            tree searches; see ``transforms.NeighbourList``); None: a fresh graph every step.
        wall_guard: end every move that would carry a centre through a wall at the wall, one
            particle radius from it (:class:`~granular_pyg.simulator.WallGuard`); the metadata
            counts the corrections (``wall_guard_corrections``, particle-steps).
        stop_when_empty: end the rollout after the step that leaves no particle in the scene
            (metadata ``stopped_empty``: the steps taken).
        precision: the network's precision, ``"32"`` or ``"bf16"`` (bfloat16 matrix products,
            about 2x faster on CPUs with AVX-512 BF16; see ``docs/results.md`` for its accuracy).
        name: how the user named ``truth`` (a file), for messages: a rollout whose particles
            all start outside the Scene is refused, one where some do is warned about
            (:func:`check_inside_scene`).

    Returns:
        A Trajectory with ``H + 1 + steps`` frames every ``k`` saved frames from
        ``start_frame``: the ``H + 1`` initial states copied from ``truth``, then the
        predictions (NaN for particles that have left); velocities are backward differences
        (m/s); metadata records the rollout's settings.

    Raises:
        InputError: no Scene, too few initial frames, a bad ``steps`` (not a whole number,
            negative, or more than the memory can hold).
        NonFiniteError: the model predicted NaN/Inf; its ``partial`` attribute holds the
            Trajectory up to the failing step (metadata ``failed_step``), nothing is lost.
        KeyboardInterrupt: Ctrl-C; its ``partial`` attribute holds the Trajectory of the
            steps finished before it (metadata ``interrupted_after_step``), or None.
    """
    wall_guard = flag("wall_guard", wall_guard)
    skin = None if skin is None else positive_number("skin", skin)
    k, initial = initial_frames(sim, truth, start_frame)
    available = available_steps(sim, truth, start_frame)
    steps = available if steps is None else whole_number("steps", steps)
    check_inside_scene(truth, int(initial[-1]), name)
    _check_fits_in_memory(steps, truth.num_particles, dtype)
    seq = torch.from_numpy(truth.positions[initial]).to(sim.dt.device, dtype)
    seq = seq.permute(1, 0, 2).contiguous()
    dt = float(sim.dt)
    t0 = float(truth.times[initial[-1]])
    settings = {"start_frame": int(start_frame), "dtype": str(dtype).removeprefix("torch.")}
    settings |= {"skin": skin, "frames_per_step": k, "wall_guard": bool(wall_guard)}
    settings["precision"] = str(precision)
    guard = WallGuard(torch.from_numpy(truth.radii).double()) if wall_guard else None
    outflow = truth.scene.outflow_z
    stopped = []

    def stop_if_empty(s: int, t: float, seq: torch.Tensor, nxt: torch.Tensor) -> bool:
        left = torch.isfinite(nxt).all(1)
        if outflow is not None:
            left &= nxt[:, 2] >= outflow
        if not bool(left.any()):
            stopped.append(s + 1)
            return True
        return False

    done_steps: list[torch.Tensor] = []  # the predictions so far (the same tensors), for Ctrl-C

    def on_step(s: int, t: float, seq: torch.Tensor, nxt: torch.Tensor) -> bool:
        done_steps.append(nxt)
        return stop_if_empty(s, t, seq, nxt) if stop_when_empty else False

    before = sim.network_dtype
    sim.set_network_precision(str(precision))
    try:
        pred = sim.rollout(
            seq,
            WallSet(truth.scene),
            t0,
            steps,
            outflow,
            progress,
            skin,
            guard,
            on_step,
            props=ParticleProps.of(truth),
        )
    except KeyboardInterrupt as exc:
        # every prediction handed to on_step is complete (the outflow, applied right after,
        # is applied again here in case Ctrl-C came in between)
        exc.partial = None
        if done_steps:
            done = torch.stack(done_steps)
            if outflow is not None:
                done[done[..., 2] < outflow] = float("nan")
            meta = settings | {"interrupted_after_step": len(done_steps)}
            exc.partial = _prediction(truth, initial, done, dt, meta)
        raise
    except NonFiniteError as exc:
        done = exc.positions_so_far
        exc.partial = _prediction(truth, initial, done, dt, settings | {"failed_step": exc.step})
        raise
    finally:
        sim.network_dtype = before
    if guard is not None:
        settings["wall_guard_corrections"] = guard.corrected
    if stopped:
        settings["stopped_empty"] = stopped[0]
    return _prediction(truth, initial, pred, dt, settings)


def _check_fits_in_memory(steps: int, particles: int, dtype: torch.dtype) -> None:
    """Refuse a rollout whose predictions (``[steps, N, 3]``, twice: tensors and the
    Trajectory) would need more than half of this machine's memory."""
    itemsize = torch.empty(0, dtype=dtype).element_size()
    need = 2 * steps * max(particles, 1) * 3 * itemsize
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not on every platform
        return
    if need > total / 2:
        most = int(total / 2 / (2 * max(particles, 1) * 3 * itemsize))
        raise InputError(
            f"steps: {steps:,} learned steps of {particles:,} particles need about "
            f"{need / 2**30:.0f} GiB, more than half of this machine's {total / 2**30:.0f} GiB; "
            f"roll out at most {most:,} steps at a time"
        )


def _prediction(
    truth: Trajectory, initial: np.ndarray, pred: torch.Tensor, dt: float, settings: dict
) -> Trajectory:
    """The Trajectory of a rollout: ``truth``'s frames ``initial``, then ``pred [S, N, 3]``."""
    history = len(initial) - 1
    positions = np.concatenate([truth.positions[initial], pred.float().cpu().numpy()])
    velocities = np.full_like(positions, np.nan)
    velocities[: history + 1] = truth.velocities[initial]
    velocities[history + 1 :] = np.diff(positions[history:], axis=0) / dt
    times = float(truth.times[initial[0]]) + dt * np.arange(len(positions))
    metadata = {
        "source": "granular_pyg.rollout",
        "truth_metadata": truth.metadata,
        "initial_frames": int(history + 1),
        "steps": int(pred.shape[0]),
        "dt": dt,
        **settings,
    }
    return dataclasses.replace(
        truth,
        positions=positions,
        velocities=velocities,
        times=times,
        metadata=metadata,
    )


def matching_frames(truth: Trajectory, pred: Trajectory) -> np.ndarray:
    """Indices of ``truth``'s frames at ``pred``'s times (a rollout every ``k`` frames).

    Raises:
        InputError: if a time of ``pred`` is not a frame of ``truth``.
    """
    idx = np.searchsorted(truth.times, pred.times - 1e-9 * truth.frame_dt)
    idx = np.clip(idx, 0, truth.num_frames - 1)
    bad = np.abs(truth.times[idx] - pred.times) > 1e-6 * truth.frame_dt
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"pred: its frame {first} (t = {pred.times[first]:.6g} s) is not a frame of the "
            "ground truth; compare a rollout with the trajectory it was made from"
        )
    return idx
