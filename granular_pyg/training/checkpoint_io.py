"""Checkpoints written atomically: a run killed while saving keeps its previous checkpoint."""

from __future__ import annotations

from typing import Any

from lightning.pytorch.plugins.io import TorchCheckpointIO

from granular_pyg.io import atomic_path

__all__ = ["AtomicCheckpointIO"]


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning's ``torch.save`` checkpoints, written to a temporary file beside the target
    and renamed onto it once complete and flushed (see :func:`granular_pyg.io.atomic_path`), so
    ``last.ckpt`` is always the old or the new checkpoint, never a truncated one."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path, storage_options: Any | None = None
    ) -> None:
        with atomic_path(path) as tmp:
            super().save_checkpoint(checkpoint, tmp, storage_options)
