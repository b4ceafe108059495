"""Using a trained model: load it from a checkpoint and roll it out over a Trajectory's Scene.

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
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from granular_pyg.errors import InputError, NonFiniteError, whole_number
from granular_pyg.io import Trajectory
from granular_pyg.pretrained import resolve_checkpoint
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator, ParticleProps, WallGuard

__all__ = [
    "available_steps",
    "initial_frames",
    "load_simulator",
    "load_weights",
    "matching_frames",
    "read_checkpoint",
    "rollout_trajectory",
    "time_step_multiple",
    "warn_outside_training",
]


def read_checkpoint(
    path: str | Path, name: str = "ckpt", map_location: str = "cpu"
) -> tuple[Path, dict]:
    """The file and contents of checkpoint ``path`` (a file or ``pretrained:<name>``).

    Raises:
        InputError: naming the option ``name``: no such file, or not a readable checkpoint.
    """
    path = resolve_checkpoint(path)
    if not path.is_file():
        raise InputError(
            f"{name}: no checkpoint at {path}; pass a file from <run>/checkpoints/ or "
            "pretrained:hopper / pretrained:drum"
        )
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as exc:  # torch raises several types for corrupt files
        raise InputError(
            f"{name}: {path} is not a readable checkpoint ({exc}); was it truncated?"
        ) from exc
    if not isinstance(ckpt, dict):
        raise InputError(f"{name}: {path} is not a granular_pyg training checkpoint")
    return path, ckpt


def load_weights(sim: LearnedSimulator, ckpt: dict, source: str) -> None:
    """Load the ``sim.*`` weights and buffers (normalisation, ``dt``) of training checkpoint
    ``ckpt`` into ``sim``.

    Raises:
        InputError: naming ``source``: the weights do not fit ``sim``'s architecture.
    """
    prefix = "sim."
    state = {k[len(prefix) :]: v for k, v in ckpt["state_dict"].items() if k.startswith(prefix)}
    missing, unexpected = sim.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise InputError(
            f"{source}: weights do not fit the model of its config (missing {missing[:5]}, "
            f"unexpected {unexpected[:5]})"
        )


def load_simulator(path: str | Path, map_location: str = "cpu") -> tuple[LearnedSimulator, dict]:
    """The trained simulator of a training checkpoint (``checkpoints/*.ckpt``), in eval mode.

    Args:
        path: a checkpoint written by ``python -m granular_pyg.train``, or
            ``pretrained:<name>`` (see :mod:`granular_pyg.pretrained`).
        map_location: device for the weights.

    Returns:
        ``(simulator, config)``: the model with its weights, normalisation statistics and ``dt``,
        and the training run's resolved config (a dict) with the checkpoint's model card under
        ``model_card`` (:mod:`granular_pyg.training.model_card`; empty for old checkpoints).
    """
    path, ckpt = read_checkpoint(path, "ckpt", map_location)
    config = ckpt.get("config")
    if not config or "model" not in config or "state_dict" not in ckpt:
        raise InputError(
            f"{path}: not a granular_pyg training checkpoint (no config or state_dict); "
            "train one with `python -m granular_pyg.train`"
        )
    sim = instantiate(OmegaConf.create(config["model"]))
    load_weights(sim, ckpt, str(path))
    config = dict(config) | {"model_card": ckpt.get("model_card") or {}}
    return sim.eval(), config


def warn_outside_training(config: dict, truth: Trajectory, name: str) -> list[str]:
    """Print one ``warning:`` line (standard error) per property of ``truth`` outside the
    model's training data (its card), naming the trajectory ``name``; returns the messages."""
    from granular_pyg.training.model_card import outside_training

    found = outside_training(config.get("model_card"), truth)
    for message in found:
        print(f"warning: {name}: {message}; the prediction may be poor", file=sys.stderr)
    return found


def whole_multiple(dt: float, frame_dt: float) -> int | None:
    """``dt / frame_dt`` (both s) when it is a whole number >= 1 (to 1e-6), else None."""
    ratio = dt / frame_dt
    k = round(ratio)
    return k if k >= 1 and abs(ratio - k) <= 1e-6 * max(1.0, ratio) else None


def time_step_multiple(sim: LearnedSimulator, frame_dt: float) -> int:
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
    truth.check_even_spacing()
    k = time_step_multiple(sim, truth.frame_dt)
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
    """
    k, initial = initial_frames(sim, truth, start_frame)
    available = available_steps(sim, truth, start_frame)
    steps = available if steps is None else whole_number("steps", steps)
    _check_fits_in_memory(steps, truth.num_particles, dtype)
    seq = torch.from_numpy(truth.positions[initial]).to(sim.dt.device, dtype)
    seq = seq.permute(1, 0, 2).contiguous()
    dt = float(sim.dt)
    t0 = float(truth.times[initial[-1]])
    settings = {"start_frame": int(start_frame), "dtype": str(dtype).removeprefix("torch.")}
    settings |= {"skin": skin, "time_step_multiple": k, "wall_guard": bool(wall_guard)}
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

    check = stop_if_empty if stop_when_empty else None
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
            check,
            props=ParticleProps.of(truth),
        )
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
