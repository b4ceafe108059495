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
from granular_pyg.metrics import beverloo, flow
from granular_pyg.scenes import Scene, WallSet

__all__ = ["PairEvaluation", "evaluate_pair"]

#: Axis whose coordinate splits the two mixing classes in a hopper (paper: z); in a drum it is
#: the horizontal axis across the drum's own (paper: x, its drum turning about y).
HOPPER_MIXING_AXIS = 2
#: Scalars of the metrics that need a scene kind, NaN where a scene of that kind cannot have
#: them (a drum without a horizontal rotation, a scene of kind ``other``).
DISCHARGE_SCALARS = (
    "discharge_rate_truth",
    "discharge_rate_pred",
    "discharge_rate_rel_error",
    "discharged_fraction_truth",
    "discharged_fraction_pred",
    "discharged_fraction_error",
    "time_to_empty_truth_s",
    "time_to_empty_pred_s",
    "beverloo_rate",
)
#: Fraction of the initial bed's mass that counts as an emptied hopper (time to empty).
EMPTY_LEVEL = 0.99
ANGLE_SCALARS = (
    "angle_of_repose_truth_deg",
    "angle_of_repose_pred_deg",
    "angle_of_repose_error_deg",
    "angle_of_repose_curve_error_deg",
    "centre_of_mass_swing_truth_m",
    "centre_of_mass_swing_pred_m",
)
#: s: a drum's bed is taken as settled from this time on (its centre of mass swing is measured
#: over the frames after it).
DRUM_SETTLED_S = 1.0
#: The paper splits the classes at its frame 30: 0.03 s at its 1 ms frames. Taken as a time,
#: so that long learned steps (20 ms) still split the bed before a hopper drains.
MIXING_TIME_S = 0.03
FLOW_BINS = 19


@dataclass
class PairEvaluation:
    """Metrics of one (ground truth, prediction) pair.

    Attributes:
        scalars: flat ``{name: number}`` (SI units; names say what, e.g.
            ``discharge_rate_rel_error``, ``angle_of_repose_error_deg``). The same keys for
            every scene of a kind: a hopper has the discharge rates, a drum the angles of
            repose, a scene of kind ``other`` both as NaN; a metric a scene cannot have
            (``mixing_entropy_error`` for ``other``) is NaN, with a warning that names it.
            ``emd_frames`` is the number of frames ``emd_mean`` averages over, the same for
            every rollout of a trajectory.
        emd_steps: ``{learned step 2^k: W2^2 (m^2)}`` for every step the rollout has; a step
            where one side has drained and the other has not counts the remaining particles'
            move to the outlet (:func:`granular_pyg.metrics.emd`).
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

    What the scene is comes from ``truth.scene.kind``: a ``hopper`` splits the mixing classes
    along z and has a discharge rate through its outlet (``params["outlet_z"]``, default 0); a
    ``drum`` splits them across its rotation axis (its rotating wall's ``motion.axis``) and has
    a dynamic angle of repose; ``other`` has neither, and the metrics it cannot have are skipped
    with a warning that names them. Leaked particles are those whose centre went through the
    scene's walls (:func:`granular_pyg.metrics.leaked_mask`), counted over the predicted
    moves (from the last initial state on) for both.

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

    scene = truth.scene
    sink = metrics.outlet_point(scene)
    emd_steps = metrics.emd_at_powers(t_pos[first - 1 :], p_pos[first - 1 :], sink=sink)
    both = np.isfinite(t_pos[first:]).all(-1) & np.isfinite(p_pos[first:]).all(-1)
    diff = (t_pos[first:] - p_pos[first:])[both]
    mean_t, mean_p = metrics.centre_of_mass(t_pos), metrics.centre_of_mass(p_pos)

    skipped: list[str] = []
    axis = _mixing_axis(scene)
    # The paper's t0, or the last frame the truth still has particles (a drained hopper).
    occupied = np.flatnonzero(np.isfinite(t_pos).all(-1).any(-1))
    if occupied.size == 0:
        raise InputError("truth: no particle is present in any frame of the rollout's span")
    after = np.flatnonzero(pred.times >= MIXING_TIME_S - 1e-9)
    mixing_frame = min(int(after[0]) if after.size else len(pred.times) - 1, int(occupied[-1]))
    if axis is None:
        skipped.append(f"mixing entropy (no mixing axis for {_kind(scene)})")
        ent_t = ent_p = np.full(len(pred.times), np.nan)
    else:
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
    walls = WallSet(scene)
    # From the last initial state on: the moves between the initial states are the truth's,
    # sampled every k frames, whose straight chords can cut a wall's corner (not the model's).
    since = slice(first - 1, None)
    leaked_p = metrics.leaked_particles(p_pos[since], scene, pred.times[since], walls=walls)
    leaked_t = metrics.leaked_particles(t_pos[since], scene, pred.times[since], walls=walls)
    scalars = {
        "steps": float(steps),
        "emd_final": metrics.emd(t_pos[-1], p_pos[-1], sink=sink),
        "emd_mean": float(np.mean(list(emd_steps.values()))) if emd_steps else float("nan"),
        "emd_frames": float(len(emd_steps)),
        "position_mse": float(np.mean(diff**2)) if diff.size else float("nan"),
        "mean_position_error": float(np.nanmean(np.linalg.norm(mean_t - mean_p, axis=1))),
        "mixing_entropy_error": _nanmean(np.abs(ent_t - ent_p)),
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
        "flow_z_truth": _column_nanmean(prof_t),
        "flow_z_pred": _column_nanmean(prof_p),
        "flow_t_truth": _mean_vz(t_vel),
        "flow_t_pred": _mean_vz(p_vel),
        "entropy_truth": ent_t,
        "entropy_pred": ent_p,
    }
    observable = _scene_observable(truth, t_pos, p_pos, pred.times, scalars, series, skipped, first)
    if skipped:
        warnings.warn(
            f"evaluate_pair: scene {scene.name!r} (kind {scene.kind!r}): skipped "
            + "; ".join(skipped)
            + "; their scalars are NaN",
            stacklevel=2,
        )
    return PairEvaluation(scalars, emd_steps, series, observable, mixing_frame)


def _kind(scene: Scene) -> str:
    return f"a scene of kind {scene.kind!r}"


def _mixing_axis(scene: Scene) -> int | np.ndarray | None:
    """What splits the mixing classes: z in a hopper, the horizontal direction across a drum's
    rotation axis (a vector, whatever the scene's frame); None for other scenes and drums
    without a horizontal rotation."""
    if scene.kind == "hopper":
        return HOPPER_MIXING_AXIS
    if scene.kind == "drum":
        axis = metrics.drum_axis(scene)
        return None if axis is None else metrics.across_drum_axis(axis)
    return None


def _nanmean(values: np.ndarray) -> float:
    """Mean of the finite values, NaN (without a warning) when there is none."""
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else float("nan")


def _column_nanmean(values: np.ndarray) -> np.ndarray:
    """``[T, B] -> [B]``: per column the mean of the finite values, NaN (without a warning)
    for a column with none (a height band no particle reached)."""
    finite = np.isfinite(values)
    total = np.where(finite, values, 0.0).sum(0)
    count = finite.sum(0)
    return np.divide(total, count, out=np.full(total.shape, np.nan), where=count > 0)


def _mean_vz(vel: np.ndarray) -> np.ndarray:
    vz = vel[..., 2]
    count = np.isfinite(vz).sum(1)
    return np.where(count > 0, np.nansum(vz, 1) / np.maximum(count, 1), np.nan)


def _scene_observable(
    truth, t_pos, p_pos, times, scalars, series, skipped, first: int = 1
) -> tuple[str, str]:
    """Hopper: discharged fraction and mass flow rate; drum: dynamic angle of repose; other:
    the fraction of particles that left (no rate, no angle: their scalars are NaN)."""
    scene = truth.scene
    if scene.kind == "drum":
        axis = metrics.drum_axis(scene)
        if axis is None:
            skipped.append(
                "dynamic angle of repose (no wall of the drum turns about a horizontal axis)"
            )
            scalars |= dict.fromkeys(ANGLE_SCALARS, float("nan"))
            series["angle_truth"] = series["angle_pred"] = np.full(len(times), np.nan)
            return "angle", "dynamic angle of repose (deg)"
        ang_t = _angles(t_pos, axis)
        ang_p = _angles(p_pos, axis)
        series["angle_truth"], series["angle_pred"] = ang_t, ang_p
        late = slice(len(times) // 2, None)
        with warnings.catch_warnings():  # no frame with a surface: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            a_t, a_p = float(np.nanmedian(ang_t[late])), float(np.nanmedian(ang_p[late]))
        scalars |= {
            "angle_of_repose_truth_deg": a_t,
            "angle_of_repose_pred_deg": a_p,
            "angle_of_repose_error_deg": abs(a_p - a_t),
            # Frame by frame: a bed that swings about the right median shows here.
            "angle_of_repose_curve_error_deg": _nanmean(np.abs(ang_p[late] - ang_t[late])),
        }
        settled = float(times[0]) + DRUM_SETTLED_S
        for who in ("truth", "pred"):
            scalars[f"centre_of_mass_swing_{who}_m"] = metrics.centre_of_mass_swing(
                series[f"mean_pos_{who}"], times, settled
            )
        return "angle", "dynamic angle of repose (deg)"
    if scene.kind != "hopper":
        skipped += [
            f"discharge rate (no outlet for {_kind(scene)})",
            f"dynamic angle of repose (no drum for {_kind(scene)})",
        ]
        scalars |= dict.fromkeys(DISCHARGE_SCALARS + ANGLE_SCALARS, float("nan"))
        # Particles below the outflow plane or gone, whatever the equipment.
        outflow = -np.inf if scene.outflow_z is None else float(scene.outflow_z)
        series["discharged_truth"] = metrics.discharged_fraction(t_pos, outflow)
        series["discharged_pred"] = metrics.discharged_fraction(p_pos, outflow)
        return "discharged", "fraction of the particles that left"
    outlet_z = metrics.outlet_height(scene)
    density = scene.materials.density
    mass = density * 4.0 / 3.0 * math.pi * truth.radii.astype(np.float64) ** 3
    # Both sides against the same initial bed (the particles above the outlet in the first
    # frame), not each against the mass it finally let out.
    bed = flow.bed_mass(t_pos, outlet_z, mass)
    opened = scene.opening_time or 0.0  # no lid: open from the start
    series["bed_mass"] = np.array(bed)
    for who, pos in (("truth", t_pos), ("pred", p_pos)):
        curve = flow.discharge_curve(pos, outlet_z, mass)
        series[f"discharged_mass_{who}"] = curve
        series[f"discharged_{who}"] = (
            np.minimum(curve / bed, 1.0) if bed > 0 else np.full(len(times), np.nan)
        )
        try:
            # From the last initial state on: copied states measure nothing of the model.
            rate, window = flow.discharge_rate(times, pos, outlet_z, mass, first_frame=first - 1)
        except InputError:
            rate, window = float("nan"), (float("nan"), float("nan"))
        series[f"rate_window_{who}"] = np.array(window)
        scalars[f"discharge_rate_{who}"] = float(rate)
        scalars[f"discharged_fraction_{who}"] = float(series[f"discharged_{who}"][-1])
        scalars[f"time_to_empty_{who}_s"] = flow.time_to_empty(
            times, pos, outlet_z, mass, level=EMPTY_LEVEL, since=opened
        )
    r_t, r_p = scalars["discharge_rate_truth"], scalars["discharge_rate_pred"]
    scalars["discharge_rate_rel_error"] = abs(r_p - r_t) / r_t if r_t > 0 else float("nan")
    scalars["discharged_fraction_error"] = (
        scalars["discharged_fraction_pred"] - scalars["discharged_fraction_truth"]
    )
    scalars["beverloo_rate"] = beverloo.scene_beverloo_rate(scene, truth.radii, outlet_z)
    series["opening_time"] = np.array(opened)
    return "discharged", "discharged fraction of the initial bed"


def _angles(pos: np.ndarray, axis: np.ndarray) -> np.ndarray:
    out = np.full(len(pos), np.nan)
    for i, frame in enumerate(pos):
        with contextlib.suppress(InputError):
            out[i] = metrics.dynamic_angle_of_repose(frame, axis=axis)
    return out
