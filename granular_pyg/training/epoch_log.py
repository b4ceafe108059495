"""The training log: one line per epoch and per validation rollout, in the run folder's
``train.log`` and, where no progress bar is shown, on standard output."""

from __future__ import annotations

import time
from pathlib import Path

import lightning as L

__all__ = ["EpochLog"]

#: Prefixes of the logged metrics a line shows, in this order (``train/loss_<objective>``: the
#: mean loss of the batches each objective took).
PREFIXES = ("train/loss", "val/loss", "val_rollout/emd", "val_rollout/position_mse")


class EpochLog(L.Callback):
    """Writes ``epoch 3/20  step 240  train/loss 0.0123  train/loss_unrolled 0.031
    val/loss 0.0150  (41 s)`` at the end of every training epoch, a ``rollout`` line whenever a
    validation rollout has logged new values, and a first line when training starts.

    Args:
        path: the file the lines are appended to (the run folder's ``train.log``), or None.
        echo: also print the lines to standard output (where no progress bar is shown).
    """

    def __init__(self, path: str | Path | None = None, echo: bool = True) -> None:
        self.path = None if path is None else Path(path)
        self.echo = echo
        self.start = time.perf_counter()
        self._last_rollout: float | None = None

    def write(self, line: str) -> None:
        """Append ``line`` to the file and echo it."""
        if self.echo:
            print(line, flush=True)
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open("a") as fh:
                fh.write(line + "\n")

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.start = time.perf_counter()
        if not trainer.is_global_zero:
            return
        limits = [f"max_epochs {trainer.max_epochs}"]
        timers = [c for c in trainer.callbacks if isinstance(c, L.pytorch.callbacks.Timer)]
        timer = timers[0] if timers else None
        budget = getattr(timer, "_duration", None)
        if budget is not None:
            limits.append(f"max_time {budget:.0f} s")
        objective = getattr(pl_module, "objective", None)
        self.write(
            f"training from step {trainer.global_step}: {', '.join(limits)}; "
            f"objective {objective!r}"
        )

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self._rollout_line(trainer)

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.sanity_checking:
            self._rollout_line(trainer)

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        self.write(
            f"epoch {trainer.current_epoch + 1}/{trainer.max_epochs}  "
            f"step {trainer.global_step}  {_values(trainer.callback_metrics)}  "
            f"({time.perf_counter() - self.start:.0f} s)"
        )

    def _rollout_line(self, trainer: L.Trainer) -> None:
        """A line when the validation rollout's EMD is new (a rollout has just run)."""
        metrics = trainer.callback_metrics
        if not trainer.is_global_zero or "val_rollout/emd" not in metrics:
            return
        emd = float(metrics["val_rollout/emd"])
        if emd == self._last_rollout:
            return
        self._last_rollout = emd
        rollout = {k: v for k, v in metrics.items() if k.startswith("val_rollout/")}
        self.write(
            f"rollout  step {trainer.global_step}  {_values(rollout)}  "
            f"({time.perf_counter() - self.start:.0f} s)"
        )


def _values(metrics) -> str:
    """``name value`` of the metrics whose names start with :data:`PREFIXES`, in that order
    (per-step emd values left out)."""
    shown = []
    for prefix in PREFIXES:
        for key in sorted(metrics):
            if key.startswith(prefix) and "emd_step_" not in key and key not in shown:
                if key.endswith("_step") and key[: -len("_step")] in metrics:
                    continue  # Lightning's per-step copy of an epoch mean
                shown.append(key)
    return "  ".join(f"{k} {float(metrics[k]):.4g}" for k in shown)
