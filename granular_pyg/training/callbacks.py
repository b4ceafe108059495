"""Callbacks: validation rollouts with EMD, position MSE and a figure in TensorBoard."""

from __future__ import annotations

import lightning as L
import numpy as np
from matplotlib.figure import Figure

from granular_pyg.inference import available_steps, matching_frames, rollout_trajectory
from granular_pyg.metrics import emd, outlet_point

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
    """Every ``every_n_epochs`` epochs, roll the model out ``steps`` learned steps on a
    validation trajectory and log ``val_rollout/emd`` (W2^2, m^2, at the last step and at
    steps 2^i), ``val_rollout/position_mse`` (m^2) and a figure of the last step.

    Args:
        every_n_epochs: rollout frequency.
        steps: learned steps (fewer if the trajectory ends first).
        trajectory: index of the validation trajectory.
    """

    def __init__(self, every_n_epochs: int = 1, steps: int = 50, trajectory: int = 0) -> None:
        self.every_n_epochs, self.steps, self.trajectory = every_n_epochs, steps, trajectory

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or trainer.fast_dev_run:
            return
        if (trainer.current_epoch + 1) % self.every_n_epochs:
            return
        if not trainer.is_global_zero:
            return
        data = trainer.datamodule.val_set
        traj = data.trajs[self.trajectory]
        sim = pl_module.sim
        was_training = sim.training
        sim.eval()
        available = available_steps(sim, traj)
        rollout = rollout_trajectory(sim, traj, min(self.steps, available), progress=False)
        sim.train(was_training)
        first, steps = rollout.metadata["initial_frames"], rollout.metadata["steps"]
        if steps == 0:
            return
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
