"""The model a checkpoint describes: built only from the package's own model classes, then its
weights, normalisation statistics and learned step loaded.

A checkpoint's saved config is data from a file the user received, not a config the user wrote:
its ``_target_`` keys are instantiated only when they name one of :data:`MODEL_TARGETS` (Hydra's
``instantiate`` would otherwise call any importable function, ``builtins.open`` or
``torch.load`` included).
"""

from __future__ import annotations

from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from granular_pyg.checkpoint.files import read_training_checkpoint
from granular_pyg.checkpoint.saved_config import migrate_config
from granular_pyg.errors import InputError
from granular_pyg.simulator import LearnedSimulator

__all__ = [
    "MODEL_TARGETS",
    "build_model",
    "check_model_config",
    "load_simulator",
    "load_weights",
    "processor_name",
    "whole_multiple",
]

#: The classes a checkpoint's model config may name (``_target_``): the package's own models.
MODEL_TARGETS = frozenset(
    {
        "granular_pyg.simulator.LearnedSimulator",
        "granular_pyg.nn.Processor",
        "granular_pyg.nn.processor.Processor",
        "granular_pyg.nn.HorizontalEquivariantProcessor",
        "granular_pyg.nn.horizontal_equivariant.HorizontalEquivariantProcessor",
    }
)


def processor_name(model: dict) -> str:
    """A saved model config's processor, for tables: its message-passing layer (``interaction``,
    ``attention``), or ``equivariant`` for the equivariant processor (which has no layer key)."""
    processor = model.get("processor") or {}
    if "layer" in processor:
        return str(processor["layer"])
    target = str(processor.get("_target_", ""))
    return "equivariant" if target.endswith("EquivariantProcessor") else target.rsplit(".", 1)[-1]


def check_model_config(model: dict, source: str) -> None:
    """Refuse a model config (from a checkpoint) that would instantiate anything but
    :data:`MODEL_TARGETS` or that holds interpolations (a saved config is resolved).

    Raises:
        InputError: naming ``source``, the key and the ``_target_``.
    """

    def walk(node, where: str) -> None:
        if isinstance(node, dict):
            target = node.get("_target_")
            if target is not None and target not in MODEL_TARGETS:
                raise InputError(
                    f"{source}: its saved config names {where}._target_={target!r}, which is not "
                    "one of the package's model classes, so it was refused unrun (a checkpoint's "
                    "config may only build " + ", ".join(sorted(MODEL_TARGETS)[:2]) + "); use a "
                    "checkpoint from a source you trust"
                )
            for key, value in node.items():
                walk(value, f"{where}.{key}")
        elif isinstance(node, list | tuple):
            for i, value in enumerate(node):
                walk(value, f"{where}[{i}]")
        elif isinstance(node, str) and "${" in node:
            raise InputError(
                f"{source}: its saved config has an interpolation at {where} ({node!r}); a saved "
                "config is resolved, so the file was edited; use a checkpoint you trust"
            )

    if not isinstance(model, dict) or "_target_" not in model:
        raise InputError(f"{source}: its saved config has no model class (model._target_)")
    walk(model, "model")


def build_model(model: dict, source: str, state: dict | None = None) -> LearnedSimulator:
    """The (untrained) model of a checkpoint's model config, after :func:`check_model_config`.

    Args:
        model: the checkpoint's ``config["model"]``.
        source: how to name the checkpoint in messages.
        state: the checkpoint's ``state_dict``: the model is first built on the ``meta`` device
            (no memory) and its tensors compared with these, so a config that does not fit its
            weights (or asks for a huge model) is refused before anything is allocated.

    Raises:
        InputError: naming ``source``: a refused config, one the model class does not take, or
            one whose tensors do not fit ``state``.
    """
    check_model_config(model, source)
    if state is not None:
        try:
            with torch.device("meta"):
                meta = _instantiate(model, source)
        except InputError:  # a class that needs real tensors to build: checked once built
            meta = None
        if meta is not None:
            _check_fits(meta, state, source)
    return _instantiate(model, source)


def _instantiate(model: dict, source: str) -> LearnedSimulator:
    try:
        sim = instantiate(OmegaConf.create(model))
    except Exception as exc:  # a key the class does not take, a bad value
        cause = exc.__cause__ or exc
        first = str(cause).splitlines()[0] if str(cause) else type(cause).__name__
        raise InputError(
            f"{source}: its saved model config does not build a model ({first}); was it written "
            "by a newer granular_pyg, or edited?"
        ) from None
    if not isinstance(sim, LearnedSimulator):
        raise InputError(f"{source}: its saved model config does not build a LearnedSimulator")
    return sim


def load_weights(sim: LearnedSimulator, ckpt: dict, source: str) -> None:
    """Load the ``sim.*`` weights and buffers (normalisation, ``dt``) of training checkpoint
    ``ckpt`` into ``sim``.

    Raises:
        InputError: naming ``source``: the weights do not fit ``sim``'s architecture (missing or
            extra tensors, or tensors of another shape: the first one is named).
    """
    _check_fits(sim, ckpt["state_dict"], source)
    prefix = "sim."
    state = {k[len(prefix) :]: v for k, v in ckpt["state_dict"].items() if k.startswith(prefix)}
    sim.load_state_dict(state, strict=True)


def _check_fits(sim: LearnedSimulator, state_dict: dict, source: str) -> None:
    """Refuse ``state_dict``'s ``sim.*`` tensors when they are not ``sim``'s (names, shapes)."""
    prefix = "sim."
    state = {k[len(prefix) :]: v for k, v in state_dict.items() if k.startswith(prefix)}
    own = sim.state_dict()
    wrong = [
        f"{k}: {list(v.shape)} in the file, {list(own[k].shape)} for the config"
        for k, v in state.items()
        if k in own and tuple(v.shape) != tuple(own[k].shape)
    ]
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    if wrong or missing or unexpected:
        detail = (
            f"{len(wrong)} of another shape, first {wrong[0]}"
            if wrong
            else f"missing {missing[:3]}, unexpected {unexpected[:3]}"
        )
        raise InputError(
            f"{source}: its weights do not fit the model its config describes ({detail}); the "
            "config and weights come from different runs or the file was edited; use the "
            "checkpoint as training wrote it"
        )


def load_simulator(
    path: str | Path, map_location: str = "cpu", name: str = "ckpt"
) -> tuple[LearnedSimulator, dict]:
    """The trained simulator of a training checkpoint (``checkpoints/*.ckpt``), in eval mode,
    read safely.

    Args:
        path: a checkpoint written by ``python -m granular_pyg.train``, or
            ``pretrained:<name>`` (see :mod:`granular_pyg.pretrained`).
        map_location: device for the weights.
        name: the option the user gave it as (for messages).

    Returns:
        ``(simulator, config)``: the model with its weights, normalisation statistics and ``dt``,
        and the training run's resolved config (a dict) with the checkpoint's model card under
        ``model_card`` (:mod:`granular_pyg.checkpoint.card`; empty for old checkpoints).
    """
    path, ckpt = read_training_checkpoint(path, name, map_location)
    config = migrate_config(ckpt["config"])  # an older checkpoint's keys brought to today's
    sim = build_model(config["model"], f"{name}: {path}", ckpt["state_dict"])
    load_weights(sim, ckpt, f"{name}: {path}")
    config = dict(config) | {"model_card": ckpt.get("model_card") or {}}
    return sim.eval(), config


def whole_multiple(dt: float, frame_dt: float) -> int | None:
    """``dt / frame_dt`` (both s) when it is a whole number >= 1 (to 1e-6), else None."""
    ratio = dt / frame_dt
    k = round(ratio)
    return k if k >= 1 and abs(ratio - k) <= 1e-6 * max(1.0, ratio) else None


def to_plain(value):
    """``value`` with OmegaConf containers turned into dicts and lists (what a checkpoint
    stores, so that it reads with the weights-only unpickler)."""
    if OmegaConf.is_config(value):
        return OmegaConf.to_container(value, resolve=True)
    if isinstance(value, dict):
        return {k: to_plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(to_plain(v) for v in value)
    return value
