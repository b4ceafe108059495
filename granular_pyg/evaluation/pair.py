"""One rollout against its ground truth: the paper's metrics and the physics engineers check."""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from granular_pyg import metrics
from granular_pyg.errors import InputError
from granular_pyg.inference import matching_frames
from granular_pyg.io import Trajectory

__all__ = ["PairEvaluation", "evaluate_pair"]

#: Axis whose coordinate splits the two mixing classes (paper: x or z), per scene kind.
MIXING_AXIS = {"hopper": 2, "drum": 0}
#: The paper splits the classes at its frame 30: 0.03 s at its 1 ms frames. Taken as a time,
#: so that long learned steps (20 ms) still split the bed before a hopper drains.
MIXING_TIME_S = 0.03
FLOW_BINS = 19


@dataclass
class PairEvaluation:
    """Metrics of one (ground truth, prediction) pair.

    Attributes:
        scalars: flat ``{name: number}`` (SI units; names say what, e.g.
            ``discharge_rate_rel_error``, ``angle_of_repose_error_deg``).
        emd_steps: ``{learned step 2^k: W2^2 (m^2)}`` while the rollout has that step.
        series: curves for the figures, ``[F]`` or ``[F, 3]`` over the rollout's frames (key
            ``times``) or ``[B]`` over z bins (``flow_z_*``).
        observable: the scene's own curve in ``series`` and its axis label.
        mixing_frame: the rollout frame where the mixing classes were split (the first at or
            after ``MIXING_TIME_S``).
    """

    scalars: dict[str, float]
    emd_steps: dict[int, float]
    series: dict[str, np.ndarray] = field(repr=False)
    observable: tuple[str, str] = ("discharged", "discharged fraction")
    mixing_frame: int = 0


def evaluate_pair(
    truth: Trajectory, pred: Trajectory, history: int | None = None
) -> PairEvaluation:
    """Compare a rollout with the ground truth it started from.

    ``pred``'s frames are matched to ``truth``'s by time (a rollout with time-step multiple k
    has every k-th frame). The first ``history`` frames of ``pred`` are the copied initial
    states and learned step ``s`` is its frame ``history - 1 + s``: EMD and position errors
    are taken over the predicted frames only, while the curves (positions, flow, mixing,
    discharge) span the whole rollout.

    Args:
        truth: LIGGGHTS ground truth with its Scene.
        pred: a rollout of ``truth`` (``granular_pyg.inference.rollout_trajectory``).
        history: initial frames in ``pred``; default its metadata's ``initial_frames``.

    Returns:
        The :class:`PairEvaluation`.
    """
    if truth.scene is None:
        raise InputError("truth: needs its Scene (walls, outflow) to be evaluated")
    if pred.num_particles != truth.num_particles:
        raise InputError(
            f"pred: {pred.num_particles} particles against the truth's {truth.num_particles}; "
            "compare a rollout with the trajectory it was made from"
        )
    first = int(history if history is not None else pred.metadata.get("initial_frames", 1))
    frames = matching_frames(truth, pred)
    t_pos, p_pos = truth.positions[frames], pred.positions
    t_vel, p_vel = truth.velocities[frames], pred.velocities
    steps = len(frames) - first
    if steps < 1:
        raise InputError("pred: has no predicted frame beyond its initial states")

    emd_steps = metrics.emd_at_powers(t_pos[first - 1 :], p_pos[first - 1 :])
    both = np.isfinite(t_pos[first:]).all(-1) & np.isfinite(p_pos[first:]).all(-1)
    diff = (t_pos[first:] - p_pos[first:])[both]
    mean_t, mean_p = metrics.centre_of_mass(t_pos), metrics.centre_of_mass(p_pos)

    kind = truth.scene.name
    axis = MIXING_AXIS.get(kind, 0)
    # The paper's t0, or the last frame the truth still has particles (a drained hopper).
    occupied = np.flatnonzero(np.isfinite(t_pos).all(-1).any(-1))
    if occupied.size == 0:
        raise InputError("truth: no particle is present in any frame of the rollout's span")
    after = np.flatnonzero(pred.times >= MIXING_TIME_S - 1e-9)
    mixing_frame = min(int(after[0]) if after.size else len(pred.times) - 1, int(occupied[-1]))
    classes = metrics.mixing_classes(t_pos, frame=mixing_frame, axis=axis)
    ent_t = metrics.mixing_entropy_curve(t_pos, classes)
    ent_p = metrics.mixing_entropy_curve(p_pos, classes)

    z_all = np.concatenate([t_pos[..., 2][np.isfinite(t_pos[..., 2])]])
    z_range = (float(z_all.min()), float(z_all.max())) if len(z_all) else (0.0, 1.0)
    prof_t = metrics.flow_profile(t_pos, t_vel, z_bins=FLOW_BINS, z_range=z_range)
    prof_p = metrics.flow_profile(p_pos, p_vel, z_bins=FLOW_BINS, z_range=z_range)
    edges = np.linspace(*z_range, FLOW_BINS + 1)

    closest = float(truth.radii.min())
    crushed_p = metrics.crushed_particles(p_pos[first:], closest)
    crushed_t = metrics.crushed_particles(t_pos[first:], closest)
    leaked_p = metrics.leaked_particles(p_pos, truth.scene, pred.times, truth.radii)
    leaked_t = metrics.leaked_particles(t_pos, truth.scene, pred.times, truth.radii)
    scalars = {
        "steps": float(steps),
        "emd_final": metrics.emd(t_pos[-1], p_pos[-1]) if both[-1].any() else float("nan"),
        "emd_mean": float(np.mean(list(emd_steps.values()))) if emd_steps else float("nan"),
        "position_mse": float(np.mean(diff**2)) if diff.size else float("nan"),
        "mean_position_error": float(np.nanmean(np.linalg.norm(mean_t - mean_p, axis=1))),
        "mixing_entropy_error": float(np.nanmean(np.abs(ent_t - ent_p))),
        "flow_profile_error": float(np.nanmean(np.abs(prof_t - prof_p))),
        "leaked_particles": float(leaked_p),
        "leaked_particles_truth": float(leaked_t),
        "crushed_particles": float(crushed_p.max(initial=0)),
        "crushed_particles_truth": float(crushed_t.max(initial=0)),
    }
    series = {
        "times": pred.times,
        "mean_pos_truth": mean_t,
        "mean_pos_pred": mean_p,
        "flow_z_centres": 0.5 * (edges[1:] + edges[:-1]),
        "flow_z_truth": np.nanmean(prof_t, axis=0),
        "flow_z_pred": np.nanmean(prof_p, axis=0),
        "flow_t_truth": _mean_vz(t_vel),
        "flow_t_pred": _mean_vz(p_vel),
        "entropy_truth": ent_t,
        "entropy_pred": ent_p,
    }
    observable = _scene_observable(truth, t_pos, p_pos, pred.times, scalars, series)
    return PairEvaluation(scalars, emd_steps, series, observable, mixing_frame)


def _mean_vz(vel: np.ndarray) -> np.ndarray:
    vz = vel[..., 2]
    count = np.isfinite(vz).sum(1)
    return np.where(count > 0, np.nansum(vz, 1) / np.maximum(count, 1), np.nan)


def _scene_observable(truth, t_pos, p_pos, times, scalars, series) -> tuple[str, str]:
    """Hopper: discharged fraction and mass flow rate; drum: dynamic angle of repose."""
    scene = truth.scene
    if scene.name == "drum":
        ang_t = _angles(t_pos)
        ang_p = _angles(p_pos)
        series["angle_truth"], series["angle_pred"] = ang_t, ang_p
        late = slice(len(times) // 2, None)
        a_t, a_p = float(np.nanmedian(ang_t[late])), float(np.nanmedian(ang_p[late]))
        with warnings.catch_warnings():  # no frame with a surface in both: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            curve = float(np.nanmean(np.abs(ang_p[late] - ang_t[late])))
        scalars |= {
            "angle_of_repose_truth_deg": a_t,
            "angle_of_repose_pred_deg": a_p,
            "angle_of_repose_error_deg": abs(a_p - a_t),
            # Frame by frame: a bed that swings about the right median shows here.
            "angle_of_repose_curve_error_deg": curve,
        }
        return "angle", "dynamic angle of repose (deg)"
    outlet_z = float(scene.params.get("outlet_z", 0.0))
    series["discharged_truth"] = metrics.discharged_fraction(t_pos, outlet_z)
    series["discharged_pred"] = metrics.discharged_fraction(p_pos, outlet_z)
    density = scene.materials.density
    mass = density * 4.0 / 3.0 * math.pi * truth.radii.astype(np.float64) ** 3
    for who, pos in (("truth", t_pos), ("pred", p_pos)):
        try:
            rate = metrics.discharge_rate(times, pos, outlet_z, mass)[0]
        except InputError:
            rate = float("nan")
        scalars[f"discharge_rate_{who}"] = float(rate)
    r_t, r_p = scalars["discharge_rate_truth"], scalars["discharge_rate_pred"]
    scalars["discharge_rate_rel_error"] = abs(r_p - r_t) / r_t if r_t > 0 else float("nan")
    return "discharged", "discharged fraction"


def _angles(pos: np.ndarray) -> np.ndarray:
    out = np.full(len(pos), np.nan)
    for i, frame in enumerate(pos):
        with contextlib.suppress(InputError):
            out[i] = metrics.dynamic_angle_of_repose(frame)
    return out
