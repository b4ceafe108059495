"""Configs saved in older checkpoints, brought to today's keys (renames and removed options)."""

from __future__ import annotations

import copy

from granular_pyg.errors import InputError

__all__ = ["migrate_config"]

#: Options that were removed because they did not help (docs/results.md, "What did not help"),
#: with the value that meant "off"; a checkpoint trained with one on cannot be resumed.
_REMOVED = {
    ("data", "wall_press"): 0.0,
    ("data", "wall_press_reach"): None,
    ("data", "wall_press_fraction"): None,
    ("data", "wall_press_approach"): 0.0,
    ("data", "keep_leaving"): False,
    ("data", "resample_noise_at_walls"): True,
    ("push_forward", "unroll_noise"): False,
    ("model", "type_scale"): 1.0,
    ("model", "normal_scale"): 1.0,
    ("model", "overlap_feature"): False,
    ("model", "rest_gate"): False,
    ("data", "clean_share"): 0.0,
    ("data", "event_share"): 0.0,
}

#: Options added later, with the value an older checkpoint's model had (off).
_ADDED = {
    ("model", "radius_feature"): False,
    ("model", "material_features"): [],
    ("model", "contact_feature"): False,
    ("model", "wall_nodes"): "triangle",  # the paper's wall nodes, before surface patches
    ("model", "walls_over_step"): False,  # the walls at a step's start
    ("model", "sleep"): False,  # every particle's acceleration as the network gives it
    ("model", "canonical_frame"): False,  # the network sees the world frame
    ("data", "augment"): False,  # windows in the recorded frame, before turns and mirrors
}


def migrate_config(config: dict) -> dict:
    """A copy of a checkpoint's resolved training config with today's keys.

    ``data.step`` becomes ``data.frames_per_step``; model options added since are set to the
    value that meant "off" (what the old model was); the old ``push_forward`` section becomes the
    ``objective`` (a Mixture of PushForward / Unrolled parts); keys the data module derived from
    it go; options removed because they did not help go when they were off.

    Raises:
        InputError: the checkpoint was trained with a removed option switched on.
    """
    cfg = copy.deepcopy(config)
    data = cfg.setdefault("data", {})
    if "step" in data:
        data["frames_per_step"] = data.pop("step")
    data.setdefault("noise_target", "velocity")
    for (section, key), off in _ADDED.items():
        if section in cfg:
            cfg[section].setdefault(key, copy.deepcopy(off))
    processor = cfg.get("model", {}).get("processor")
    if isinstance(processor, dict) and str(processor.get("_target_", "")).endswith(
        "EquivariantProcessor"
    ):
        processor.setdefault("wall_sum", False)  # each step's mean only, before the wall sum
    for section, key in (("data", "push_forward_steps"), ("data", "unroll_steps")):
        cfg.get(section, {}).pop(key, None)
    for (section, key), off in _REMOVED.items():
        value = cfg.get(section, {}).pop(key, off)
        if off is not None and value != off:
            raise InputError(
                f"the checkpoint was trained with {section}.{key}={value!r}, an option removed "
                "because it did not help (docs/results.md); train a new model"
            )
    old = cfg.pop("push_forward", None)
    if old is not None and "objective" not in cfg:
        parts = {}
        if old.get("unroll_steps", 0) and old.get("unroll_prob", 0.0):
            parts["unrolled"] = {
                "_target_": "granular_pyg.training.objectives.Unrolled",
                "steps": old["unroll_steps"],
                "share": old["unroll_prob"],
            }
        if old.get("push_forward_steps", 0) and old.get("push_forward_prob", 0.0):
            parts["push_forward"] = {
                "_target_": "granular_pyg.training.objectives.PushForward",
                "max_steps": old["push_forward_steps"],
                "share": old["push_forward_prob"],
            }
        cfg["objective"] = {"_target_": "granular_pyg.training.objectives.Mixture", "parts": parts}
    return cfg
