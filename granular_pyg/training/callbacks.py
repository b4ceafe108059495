"""Callbacks: validation rollouts (by epoch, optimiser steps or wall time) with EMD, position
MSE and a figure in TensorBoard."""

from __future__ import annotations

import contextlib
import time

import lightning as L
import numpy as np
import torch
from matplotlib.figure import Figure

from granular_pyg.errors import InputError
from granular_pyg.inference import (
    available_steps,
    initial_frames,
    matching_frames,
    rollout_trajectory,
)
from granular_pyg.metrics import emd, outlet_point
from granular_pyg.scenes.wall_set import WallSet

__all__ = ["RolloutValidation", "rollout_figure"]


def rollout_figure(truth: np.ndarray, pred: np.ndarray, title: str):
    """x-z scatter of ground truth (filled) against prediction (open) for one frame."""
    fig = Figure(figsize=(4.5, 4.5))
    ax = fig.subplots()
    ax.scatter(truth[:, 0], truth[:, 2], s=4, c="tab:blue", label="LIGGGHTS")
    ax.scatter(
        pred[:, 0],
        pred[:, 2],
        s=6,
        facecolors="none",
        edgecolors="tab:red",
        lw=0.5,
        label="learned",
    )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    return fig


def _emd(truth: np.ndarray, pred: np.ndarray, sink: np.ndarray | None) -> float:
    """W2^2 (m^2); where one side has drained and the other has not, the remaining particles'
    move to the outlet point ``sink`` (:func:`~granular_pyg.metrics.emd`), NaN without one."""
    drained = [not np.isfinite(x).all(1).any() for x in (truth, pred)]
    if sink is None and drained[0] != drained[1]:
        return float("nan")
    return emd(truth, pred, sink=sink)


class RolloutValidation(L.Callback):
    """Roll the model out ``steps`` learned steps on a validation trajectory and log
    ``val_rollout/emd`` (W2^2, m^2, at the last step and at steps 2^i),
    ``val_rollout/position_mse`` (m^2) and a figure of the last step.

    When: after every ``every_n_epochs``-th validation epoch, and, independently, during
    training every ``every_n_steps`` optimiser steps and/or every ``every_seconds`` seconds of
    wall time (a short fine-tuning run whose epochs take minutes still sees its rollouts);
    ``None`` switches a trigger off. With a weight average (``optim.ema_decay``) every rollout
    runs with the averaged weights, what validation and checkpoints hold.

    Args:
        every_n_epochs: rollout after every n-th validation epoch, or None.
        steps: learned steps (fewer if the trajectory ends first).
        trajectory: index of the validation trajectory.
        every_n_steps: rollout every n optimiser steps, or None.
        every_seconds: rollout every so many seconds of training (s), or None.
        start: ``"first_frame"``, or ``"event"``: from the initial states whose first learned
            step holds the trajectory's first wall event (a lid removed, a drum that starts,
            stops or reverses) halfway through, so that a model which never lets a bed at rest
            go shows in the rollout (a hopper's first 0.5 s are at rest); from the first frame
            where the trajectory has no such event.
    """

    def __init__(
        self,
        every_n_epochs: int | None = 1,
        steps: int = 50,
        trajectory: int = 0,
        every_n_steps: int | None = None,
        every_seconds: float | None = None,
        start: str = "first_frame",
    ) -> None:
        if start not in ("first_frame", "event"):
            raise InputError(
                f"rollout_validation.start: expected 'first_frame' or 'event', got {start!r}"
            )
        for name, value in (
            ("every_n_epochs", every_n_epochs),
            ("every_n_steps", every_n_steps),
            ("every_seconds", every_seconds),
        ):
            if value is not None and not value > 0:
                raise InputError(
                    f"rollout_validation.{name}: expected a positive number or null, got {value}"
                )
        self.every_n_epochs, self.steps, self.trajectory = every_n_epochs, steps, trajectory
        self.every_n_steps, self.every_seconds = every_n_steps, every_seconds
        self.start = start
        self._last_step, self._last_time = 0, time.perf_counter()
        self.rollouts = 0

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._last_step, self._last_time = trainer.global_step, time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        due_steps = self.every_n_steps is not None and step - self._last_step >= self.every_n_steps
        due_time = (
            self.every_seconds is not None
            and time.perf_counter() - self._last_time >= self.every_seconds
        )
        if due_steps or due_time:
            self._last_step, self._last_time = step, time.perf_counter()
            self._rollout(trainer, pl_module)

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or self.every_n_epochs is None:
            return
        if (trainer.current_epoch + 1) % self.every_n_epochs:
            return
        self._rollout(trainer, pl_module)

    def start_frame(self, sim, traj) -> int:
        """The rollout's first frame in ``traj`` (see ``start``)."""
        if self.start == "first_frame" or traj.scene is None:
            return 0
        k, initial = initial_frames(sim, traj, 0)
        earliest = float(traj.times[initial[-1]])
        later = [e for e in WallSet(traj.scene).event_times() if e > earliest + 1e-9]
        if not later:
            return 0
        # the last initial state half a learned step before the event (at it when k = 1: a
        # wall removed at a step's end is there for that step)
        before = later[0] - (k - 1) / 2 * traj.frame_dt + 1e-6 * traj.frame_dt
        last = int(np.searchsorted(traj.times, before, "right")) - 1
        return max(0, last - (len(initial) - 1) * k)

    def _rollout(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.fast_dev_run or not trainer.is_global_zero:
            return
        data = trainer.datamodule.val_set
        traj = data.trajs[self.trajectory]
        sim = pl_module.sim
        was_training = sim.training
        sim.eval()
        start = self.start_frame(sim, traj)
        available = available_steps(sim, traj, start)
        averaged = getattr(pl_module, "averaged_weights", contextlib.nullcontext)
        with torch.no_grad(), averaged():
            rollout = rollout_trajectory(
                sim, traj, min(self.steps, available), start_frame=start, progress=False
            )
        sim.train(was_training)
        first, steps = rollout.metadata["initial_frames"], rollout.metadata["steps"]
        if steps == 0:
            return
        self.rollouts += 1
        pred = rollout.positions[first:]
        truth = traj.positions[matching_frames(traj, rollout)[first:]]
        both = np.isfinite(truth).all(-1) & np.isfinite(pred).all(-1)
        mse = float(np.mean((truth[both] - pred[both]) ** 2)) if both.any() else float("nan")
        sink = outlet_point(traj.scene) if traj.scene is not None else None
        metrics = {
            "val_rollout/position_mse": mse,
            "val_rollout/emd": _emd(truth[-1], pred[-1], sink),
        }
        step = 1
        while step <= steps:
            metrics[f"val_rollout/emd_step_{step}"] = _emd(truth[step - 1], pred[step - 1], sink)
            step *= 2
        for name, value in metrics.items():
            pl_module.log(name, value, rank_zero_only=True)
        experiment = getattr(trainer.logger, "experiment", None)
        if experiment is not None and hasattr(experiment, "add_figure"):
            t_end = rollout.times[-1]
            title = f"epoch {trainer.current_epoch}, step {steps} (t = {t_end:.3f} s)"
            experiment.add_figure(
                "val_rollout/last_frame",
                rollout_figure(truth[-1], pred[-1], title),
                global_step=trainer.global_step,
            )
