"""One log line per epoch, for training runs whose output is not a terminal."""

from __future__ import annotations

import time

import lightning as L

__all__ = ["EpochLog"]

#: Logged metrics printed per epoch, when present.
KEYS = ("train/loss", "val/loss", "val_rollout/emd")


class EpochLog(L.Callback):
    """Prints ``epoch 3/20  step 240  train/loss 0.0123  val/loss 0.0150  (41 s)`` at the end of
    every training epoch: the progress bar's information, once per epoch instead of per batch."""

    def __init__(self) -> None:
        self.start = time.perf_counter()

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        metrics = trainer.callback_metrics
        values = "  ".join(f"{k} {float(metrics[k]):.4g}" for k in KEYS if k in metrics)
        elapsed = time.perf_counter() - self.start
        print(
            f"epoch {trainer.current_epoch + 1}/{trainer.max_epochs}  "
            f"step {trainer.global_step}  {values}  ({elapsed:.0f} s)",
            flush=True,
        )
