"""Fine-tuning: train on new data starting from a trained model (``init=pretrained:<name>`` or a
checkpoint), keeping its architecture, weights and normalisation; the optimiser starts afresh.

:func:`with_initial_model` rewrites the composed training config before anything is built: the
model section becomes the checkpoint's, the data's history and noise settings follow the
checkpoint's training run, and ``data.frames_per_step`` is set so that the learned step stays
the model's (``k = dt / frame spacing`` of the new data, a whole number).
:func:`load_initial_weights` then puts the weights and statistics back after the data module
has computed its own.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from granular_pyg.checkpoint.files import read_training_checkpoint
from granular_pyg.checkpoint.model import check_model_config, load_weights, whole_multiple
from granular_pyg.checkpoint.saved_config import migrate_config
from granular_pyg.config import flatten
from granular_pyg.data.windows import load_split
from granular_pyg.errors import InputError
from granular_pyg.io import read_trajectory
from granular_pyg.simulator import LearnedSimulator

__all__ = [
    "HONOURED_MODEL_KEYS",
    "INHERITED_DATA_KEYS",
    "load_initial_weights",
    "merge_cards",
    "with_initial_model",
    "with_wall_sum",
]

#: Data settings a fine-tuning run takes over from the initial model's training run.
INHERITED_DATA_KEYS = ("history", "noise_std", "noise_target")
#: Model keys a fine-tuning run may change: how the graph is searched, how a step sees the
#: walls (an older model can learn to see a lid removed or a drum started during the step, or
#: a wall node per surface patch instead of per triangle),
#: sleeping and the scene's own frame (rules without weights) and the equivariant
#: processor's wall sum (its weights start at zero: the initial model exactly).
HONOURED_MODEL_KEYS = (
    "graph_backend",
    "max_num_neighbors",
    "walls_over_step",
    "wall_nodes",
    "sleep",
    "canonical_frame",
    "processor.wall_sum",
)


def _read(init: str) -> dict:
    path, ckpt = read_training_checkpoint(init, "init")
    ckpt["config"] = migrate_config(ckpt["config"])
    check_model_config(ckpt["config"]["model"], f"init: {path}")
    return ckpt


def _override_key(override: str) -> tuple[str, str] | None:
    """``(key, value)`` of a ``key=value`` command-line override (``+``/``++`` stripped), or
    None for a deletion (``~key``) or something else."""
    if "=" not in override or override.startswith("~"):
        return None
    key, value = override.split("=", 1)
    return key.lstrip("+"), value


def _refuse_unhonoured(overrides: Sequence[str], saved: dict, init: str) -> list[str]:
    """Check the user's command-line ``overrides`` against what fine-tuning keeps from the
    initial model; returns the model overrides it honours (:data:`HONOURED_MODEL_KEYS`).

    Raises:
        InputError: an override of the model (or of its group), of an inherited data key, or of
            ``data.frames_per_step``, whose value is not the initial model's.
    """
    model, data = flatten(saved.get("model", {})), flatten(saved.get("data", {}))
    honoured = []
    for override in overrides:
        parsed = _override_key(override)
        if parsed is None:
            continue
        key, value = parsed
        if key == "model" or key.startswith("model/"):
            raise InputError(
                f"{override}: fine-tuning keeps the model of init={init}; drop {override}, or "
                "train a new model without init="
            )
        section, _, rest = key.partition(".")
        if section == "model" and rest:
            if rest in HONOURED_MODEL_KEYS:
                honoured.append(override)
                continue
            if rest in model and str(model[rest]).lower() == value.strip("'\"").lower():
                continue
            was = f"it has {model[rest]!r}" if rest in model else "it has no such key"
            raise InputError(
                f"{override}: fine-tuning keeps the architecture of init={init} ({was}); drop "
                "the override, or train a new model without init="
            )
        if section == "data" and rest in (*INHERITED_DATA_KEYS, "frames_per_step"):
            if rest in data and str(data[rest]).lower() == value.strip("'\"").lower():
                continue
            why = (
                "set from the model's learned step and your frame spacing"
                if rest == "frames_per_step"
                else f"taken from the model's training run: {data.get(rest)!r}"
            )
            raise InputError(
                f"{override}: fine-tuning cannot honour it (data.{rest} is {why}); drop the "
                "override, or train a new model without init="
            )
    return honoured


def _frame_spacing(cfg: DictConfig) -> float:
    """Frame spacing (s) of the first training trajectory of ``cfg.data``."""
    listed = (cfg.data.get("trajectories") or {}).get("train")
    files = list(listed) if listed else load_split(cfg.data.root, cfg.data.sample, "train")
    if not files:
        raise InputError("data: the training split is empty; fine-tuning needs a trajectory")
    return read_trajectory(files[0]).frame_dt


def with_initial_model(cfg: DictConfig, overrides: Sequence[str] = ()) -> tuple[DictConfig, dict]:
    """``cfg`` with the model of checkpoint ``cfg.init``, and the checkpoint.

    Returns:
        ``(config, checkpoint)``: a copy of ``cfg`` whose ``model`` section is the
        checkpoint's (with its learned step ``dt``, s), whose data history and noise follow the
        checkpoint's run, and whose ``data.frames_per_step`` is ``dt`` over the new data's frame
        spacing (``data.augment`` false for a model that sees each scene in its own frame:
        random frames would be undone); the loaded checkpoint dict.

    Args:
        cfg: the composed training config, with ``init``.
        overrides: the user's command-line overrides (``model.latent=32``...): those that
            fine-tuning cannot honour (the architecture, the inherited data keys) are refused.

    Raises:
        InputError: a missing, unsafe or unreadable checkpoint, an override it cannot honour,
            or new data whose frame spacing the model's step is not a whole multiple of.
    """
    ckpt = _read(str(cfg.init))
    saved = ckpt["config"]
    honoured = _refuse_unhonoured(overrides, saved, str(cfg.init))
    cfg = OmegaConf.create(OmegaConf.to_container(cfg, resolve=False))
    dt = float(saved["model"].get("dt") or 0.0)
    if dt <= 0:
        raise InputError(f"init: {cfg.init} does not record its learned step (model.dt)")
    with open_dict(cfg):
        kept = {key: OmegaConf.select(cfg, key) for key, _ in map(_override_key, honoured)}
        cfg.model = OmegaConf.create(saved["model"])
        for key, value in kept.items():
            OmegaConf.update(cfg, key, value)
        for key in INHERITED_DATA_KEYS:
            if key in saved.get("data", {}):
                cfg.data[key] = saved["data"][key]
        frame_dt = _frame_spacing(cfg)
        k = whole_multiple(dt, frame_dt)
        if k is None:
            raise InputError(
                f"init: the model's learned step {dt:g} s is not a whole multiple of the new "
                f"data's frame spacing {frame_dt:g} s; record frames every {dt:g} s / k"
            )
        cfg.data.frames_per_step = k
        if cfg.model.get("canonical_frame"):  # it sees each window in its scene's own frame
            cfg.data.augment = False
        if cfg.model.processor.get("wall_sum"):
            if not str(cfg.model.processor.get("_target_", "")).endswith("EquivariantProcessor"):
                raise InputError(
                    f"model.processor.wall_sum: only the equivariant processor has it; init="
                    f"{cfg.init} has {cfg.model.processor.get('_target_')}; drop the override"
                )
            ckpt["state_dict"] = with_wall_sum(ckpt["state_dict"], int(cfg.model.latent))
    return cfg, ckpt


def with_wall_sum(state_dict: dict, latent: int) -> dict:
    """``state_dict`` (``sim.*`` keys, an equivariant model) with each processor step's node
    MLP widened by ``latent`` zero input columns for the wall sum
    (:class:`~granular_pyg.nn.HorizontalEquivariantProcessor`'s ``wall_sum``, the last input
    block): the model without it, exactly. A state dict that has them is returned as is."""
    out = dict(state_dict)
    for key, weight in state_dict.items():
        if not (
            key.startswith("sim.model.processor.layers.") and key.endswith("node_mlp.0.weight")
        ):
            continue
        layer = key[: -len("node_mlp.0.weight")]
        channels = state_dict[layer + "channel_mix.weight"].shape[0]
        if weight.shape[1] == 2 * latent + channels:  # without the wall sum (3L + C with it)
            out[key] = torch.cat([weight, weight.new_zeros((weight.shape[0], latent))], dim=1)
    return out


def load_initial_weights(sim: LearnedSimulator, ckpt: dict) -> None:
    """Load the checkpoint's weights and normalisation statistics into ``sim`` (after the data
    module set its own); the learned step must be unchanged."""
    dt = float(sim.dt)
    load_weights(sim, ckpt, "init")
    if abs(float(sim.dt) - dt) > 1e-9 * max(dt, 1e-30):
        raise InputError(f"init: learned step {float(sim.dt):g} s, the data gives {dt:g} s")


def merge_cards(initial: dict, new: dict, init: str) -> dict:
    """The card of a fine-tuned model: ``new``'s, with each training-data range widened to
    cover ``initial``'s too, and the source recorded under ``fine_tuned_from``."""
    if not initial or not new:
        return dict(new or initial) | {"fine_tuned_from": init}
    old_data, data = initial.get("training_data", {}), dict(new.get("training_data", {}))

    def union(a, b):
        return [min(a[0], b[0]), max(a[1], b[1])]

    for key in ("particle_radius_m", "particles", "frame_dt_s"):
        if key in old_data and key in data:
            data[key] = union(old_data[key], data[key])
    materials = dict(data.get("materials", {}))
    for name, bounds in old_data.get("materials", {}).items():
        materials[name] = union(bounds, materials[name]) if name in materials else bounds
    data["materials"] = materials
    data["scene_kinds"] = sorted(
        set(data.get("scene_kinds", [])) | set(old_data.get("scene_kinds", []))
    )
    data["trajectories"] = int(data.get("trajectories", 0)) + int(old_data.get("trajectories", 0))
    return dict(new) | {"training_data": data, "fine_tuned_from": init}
