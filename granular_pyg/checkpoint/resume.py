"""What a training checkpoint stores besides the weights (the run's config and model card), and
the check that a run may resume from it."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from granular_pyg.checkpoint.files import read_checkpoint
from granular_pyg.checkpoint.model import to_plain
from granular_pyg.checkpoint.saved_config import migrate_config
from granular_pyg.config import flatten
from granular_pyg.errors import InputError

__all__ = ["DERIVED_KEYS", "RESUME_KEYS", "check_resume", "saved_config"]

#: Config sections that must match between a checkpoint and the run that resumes it.
RESUME_KEYS = ("model", "data")
#: Keys set from the data at the start of training (the learned step is the data's frame
#: spacing times data.frames_per_step, both compared), so a checkpoint stores the real value.
DERIVED_KEYS = {"model.dt"}


def saved_config(cfg: DictConfig, card: dict) -> dict:
    """The run's config as a checkpoint stores it: resolved, plain dicts and lists (readable by
    the weights-only unpickler), with the learned step the data set (``card["dt_s"]``)."""
    config = to_plain(OmegaConf.to_container(cfg, resolve=True))
    config["model"]["dt"] = card.get("dt_s", config["model"].get("dt"))
    return config


def check_resume(ckpt_path: str, cfg: DictConfig) -> None:
    """Refuse to resume from ``ckpt_path`` a run whose model or data config differs.

    The file is read safely (:func:`granular_pyg.checkpoint.files.read_checkpoint`), so a
    hostile file is refused here, before Lightning reads it.

    Raises:
        InputError: naming ``ckpt_path``: an unsafe or unreadable file, one that is no training
            checkpoint (a bare state_dict, no loop state), or one trained with other keys (listed).
    """
    path, ckpt = read_checkpoint(ckpt_path, "ckpt_path")
    if "state_dict" not in ckpt or "optimizer_states" not in ckpt:
        what = (
            "a slim (pretrained or exported) checkpoint without optimiser and loop state"
            if "state_dict" in ckpt
            else "a bare state_dict"
            if ckpt and all(hasattr(v, "shape") for v in ckpt.values())
            else "not a Lightning training checkpoint"
        )
        raise InputError(
            f"ckpt_path: {path} is {what}, so training cannot resume from it; resume from "
            "<run>/checkpoints/last.ckpt, or start from its weights with init=" + str(path)
        )
    saved = ckpt.get("config")
    if saved is None:
        return
    saved = migrate_config(saved)
    now = OmegaConf.to_container(cfg, resolve=True)
    differ = []
    for section in RESUME_KEYS:
        old, new = flatten(saved.get(section, {})), flatten(now.get(section, {}))
        differ += [
            f"{section}.{k}: {old.get(k)!r} -> {new.get(k)!r}"
            for k in sorted(set(old) | set(new))
            if old.get(k) != new.get(k) and f"{section}.{k}" not in DERIVED_KEYS
        ]
    if differ:
        raise InputError(
            f"{path} was trained with a different config; these keys differ:\n  "
            + "\n  ".join(differ)
            + "\nresume with the same model/data overrides"
        )
