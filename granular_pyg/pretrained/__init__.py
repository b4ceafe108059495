"""Small pretrained checkpoints shipped with the package, so that rollouts and the demo's
evaluation work without training first.

Pass ``ckpt=pretrained:<name>`` wherever a checkpoint is asked for (``rollout``, ``evaluate``,
``load_simulator``). Each file holds only the model's config and weights (no optimiser state)
and a ``pretrained`` record of what it was trained on; see the README's results section for how
well each does. Made with ``python -m granular_pyg.pretrained.export``. The names and the
reading live in :mod:`granular_pyg.checkpoint` (re-exported here).
"""

from granular_pyg.checkpoint.files import PREFIX, PRETRAINED, resolve_checkpoint

__all__ = ["PREFIX", "PRETRAINED", "resolve_checkpoint"]
