"""Small pretrained checkpoints shipped with the package, so that rollouts and the demo's
evaluation work without training first.

Pass ``ckpt=pretrained:<name>`` wherever a checkpoint is asked for (``rollout``, ``evaluate``,
``load_simulator``). Each file holds only the model's config and weights (no optimiser state)
and a ``pretrained`` record of what it was trained on; see the README's results section for how
well each does. Made with ``python -m granular_pyg.pretrained.export``.
"""

from __future__ import annotations

from pathlib import Path

from granular_pyg.errors import InputError

__all__ = ["PREFIX", "PRETRAINED", "resolve_checkpoint"]

PREFIX = "pretrained:"

#: name -> file in this folder.
PRETRAINED = {
    "hopper": "hopper_v3.ckpt",
    "drum": "drum_v3.ckpt",
    "fast_hopper": "fast_hopper_v3.ckpt",  # latent 32, k = 16: the speed model
    "fast_drum": "fast_drum_v3.ckpt",  # latent 32, k = 8: the drum's speed model
}


def resolve_checkpoint(ckpt: str | Path) -> Path:
    """The file of ``ckpt``: ``pretrained:<name>`` names a shipped checkpoint, anything else is
    a path.

    Raises:
        InputError: an unknown or missing pretrained name (listing the available ones).
    """
    text = str(ckpt)
    if not text.startswith(PREFIX):
        return Path(ckpt)
    name = text[len(PREFIX) :]
    here = Path(__file__).parent
    available = sorted(n for n, f in PRETRAINED.items() if (here / f).is_file())
    if name not in available:
        raise InputError(
            f"ckpt: no pretrained model {name!r}; available: "
            + ", ".join(f"{PREFIX}{n}" for n in available)
        )
    return here / PRETRAINED[name]
