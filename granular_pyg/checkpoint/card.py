"""The model card a checkpoint carries: what the model does, what it was trained on, and the
check that tells a user when a trajectory lies outside that.

Card keys: ``dt_s`` (the learned step, s), ``cutoff_m`` (the radius graph's cut-off, m),
``variant`` (``none``/``single``/``both``: V1/V2/V3), ``history``, ``frames_per_step``, and
``training_data``: ``trajectories``, ``scene_kinds``, and ``[min, max]`` ranges of
``particle_radius_m``, ``particles``, ``frame_dt_s`` and each of ``materials`` (the Scene's
:class:`~granular_pyg.scenes.Materials` fields, SI units).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from granular_pyg.io import Trajectory
from granular_pyg.scenes import Scene

__all__ = ["card_of_trajectories", "model_card", "outside_training"]

#: Relative slack of the range checks (a value equal to a bound up to round-off is inside).
RANGE_SLACK = 1e-6


def _range(values: Iterable[float]) -> list[float]:
    """``[min, max]`` of ``values``; an empty list when there are none."""
    values = [float(v) for v in values]
    return [min(values), max(values)] if values else []


def model_card(
    dt: float,
    cutoff: float,
    variant: str,
    history: int,
    frames_per_step: int,
    data: list[tuple[Scene, np.ndarray]],
) -> dict:
    """The card of a model with learned step ``dt`` (s) and cut-off ``cutoff`` (m), trained on
    ``data``: one ``(scene, radii [N] m)`` per training trajectory."""
    if not data:
        return {}
    scenes = [scene for scene, _ in data]
    fields = [f.name for f in dataclasses.fields(scenes[0].materials)]
    return {
        "dt_s": float(dt),
        "cutoff_m": float(cutoff),
        "variant": str(variant),
        "history": int(history),
        "frames_per_step": int(frames_per_step),
        "training_data": {
            "trajectories": len(data),
            "scene_kinds": sorted({s.kind for s in scenes}),
            "particle_radius_m": _range(
                r for _, radii in data if len(radii) for r in (radii.min(), radii.max())
            )
            or [0.0, 0.0],
            "particles": [int(v) for v in _range(len(radii) for _, radii in data)],
            "frame_dt_s": _range(s.frame_dt for s in scenes),
            "materials": {k: _range(getattr(s.materials, k) for s in scenes) for k in fields},
        },
    }


def card_of_trajectories(
    trajectories: list[Trajectory], dt: float, cutoff: float, variant: str, history: int, k: int
) -> dict:
    """:func:`model_card` of training trajectories (those without a Scene are left out)."""
    data = [(t.scene, t.radii) for t in trajectories if t.scene is not None]
    return model_card(dt, cutoff, variant, history, k, data)


def _outside(value: float, bounds: list[float]) -> bool:
    lo, hi = bounds
    slack = RANGE_SLACK * max(abs(lo), abs(hi), 1e-30)
    return value < lo - slack or value > hi + slack


def outside_training(card: dict | None, truth: Trajectory) -> list[str]:
    """One message per property of ``truth`` outside the card's training data, naming the
    value and the range (an empty list when it is inside, or when there is no card; one
    message saying so when the card, a file's content, is malformed)."""
    try:
        return _outside_training(card, truth)
    except (TypeError, ValueError, KeyError, IndexError, AttributeError):
        return ["the checkpoint's model card is malformed, so its training ranges are not checked"]


def _outside_training(card: dict | None, truth: Trajectory) -> list[str]:
    data = (card or {}).get("training_data")
    if not data or truth.scene is None:
        return []
    found = []
    kind = truth.scene.kind
    if kind not in data["scene_kinds"]:
        found.append(f"scene kind {kind!r}: the model was trained on {data['scene_kinds']}")
    bounds = data["particle_radius_m"]
    lo, hi = (float(truth.radii.min()), float(truth.radii.max())) if truth.num_particles else (0, 0)
    if truth.num_particles and bounds and (_outside(lo, bounds) or _outside(hi, bounds)):
        found.append(
            f"particle radius {lo:.4g}-{hi:.4g} m: the model was trained on "
            f"{bounds[0]:.4g}-{bounds[1]:.4g} m"
        )
    for name, bounds in data["materials"].items():
        value = getattr(truth.scene.materials, name, None)
        if value is not None and _outside(float(value), bounds):
            found.append(
                f"{name} {value:.4g}: the model was trained on {bounds[0]:.4g}-{bounds[1]:.4g}"
            )
    spacing = data["frame_dt_s"]
    if _outside(truth.frame_dt, spacing) and card.get("dt_s"):
        found.append(
            f"frame spacing {truth.frame_dt:.4g} s: the model was trained on frames every "
            f"{spacing[0]:.4g}-{spacing[1]:.4g} s"
        )
    return found
