"""Rigid poses of a wall from its dumped vertices, and the one constant motion behind them.

A pose maps mesh-frame points ``x`` to ``rot @ x + shift``. :func:`fit_pose` finds the pose
that best maps a reference mesh onto a dumped copy of it (Kabsch / orthogonal Procrustes, least
squares) and :func:`pose_deviation` measures how far it misses. :func:`fit_motion` turns a
sequence of poses over time into one :class:`~granular_pyg.scenes.WallMotion`: a constant
rotation (``omega`` about a fitted axis and origin) or a constant-velocity translation, each
with a start and an optional stop time, or refuses when no single motion reproduces every pose.

Tolerance: LIGGGHTS writes mesh dumps with 6 significant digits (``%g``), so a coordinate
``c`` carries a rounding error up to ``5e-6 |c|``; :func:`dump_tolerance` is
``1e-6 m + 1e-6`` relative plus that rounding.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from granular_pyg.scenes.scene import WallMotion

__all__ = [
    "MotionFitError",
    "Pose",
    "dump_tolerance",
    "fit_motion",
    "fit_pose",
    "pose_deviation",
]

#: Absolute part of the pose tolerance (m).
ABS_TOLERANCE = 1e-6
#: Relative part of the pose tolerance, plus the 6-digit rounding of LIGGGHTS's mesh dumps.
REL_TOLERANCE = 1e-6 + 5e-6


class MotionFitError(ValueError):
    """No single rotation or translation reproduces the poses; the message says why."""


@dataclass(frozen=True)
class Pose:
    """A rigid pose ``x -> rot @ x + shift``: ``rot [3, 3]`` (proper rotation), ``shift [3]``
    (m)."""

    rot: np.ndarray
    shift: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """``[P, 3]`` posed copy of ``points [P, 3]`` (m)."""
        return points @ self.rot.T + self.shift

    def then(self, other: Pose) -> Pose:
        """The pose ``other`` after ``self``: ``x -> other(self(x))``."""
        return Pose(other.rot @ self.rot, other.rot @ self.shift + other.shift)

    def inverse(self) -> Pose:
        """The inverse pose."""
        return Pose(self.rot.T, -self.rot.T @ self.shift)


IDENTITY = Pose(np.eye(3), np.zeros(3))


def dump_tolerance(points: np.ndarray) -> float:
    """Largest deviation (m) accepted between ``points [P, 3]`` (m) as dumped and as posed:
    ``1e-6 m + 6e-6 * max |coordinate|`` (1e-6 relative plus the dump's 6-digit rounding)."""
    scale = float(np.abs(points).max()) if points.size else 0.0
    return ABS_TOLERANCE + REL_TOLERANCE * scale


def fit_pose(reference: np.ndarray, target: np.ndarray) -> Pose:
    """The least-squares rigid pose mapping ``reference [P, 3]`` onto ``target [P, 3]`` (m),
    point ``i`` onto point ``i`` (Kabsch: SVD of the centred cross-covariance, reflections
    excluded). Works for planar point sets too."""
    ref = np.asarray(reference, np.float64)
    tgt = np.asarray(target, np.float64)
    ref_c, tgt_c = ref.mean(0), tgt.mean(0)
    u, _, vt = np.linalg.svd((ref - ref_c).T @ (tgt - tgt_c))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return Pose(rot, tgt_c - rot @ ref_c)


def pose_deviation(reference: np.ndarray, target: np.ndarray, pose: Pose) -> float:
    """Largest coordinate difference (m) between ``pose`` applied to ``reference [P, 3]`` and
    ``target [P, 3]``."""
    if not len(reference):
        return 0.0
    return float(np.abs(pose.apply(reference) - target).max())


def fit_motion(
    times: np.ndarray,
    poses: list[Pose],
    reference: np.ndarray,
    tolerance: float,
    dem_dt: float | None = None,
) -> WallMotion:
    """One constant motion that reproduces every pose of a wall.

    Args:
        times: ``[K]`` strictly increasing times (s) of the poses.
        poses: ``K`` poses relative to the wall's pose at ``times[0]`` (the first is the
            identity, up to rounding).
        reference: ``[P, 3]`` the wall's points (m) at ``times[0]``; deviations are measured on
            them.
        tolerance: largest accepted deviation (m) of any point at any time.
        dem_dt: the DEM time step (s); start and stop times are snapped to its multiples (a
            LIGGGHTS motion starts and stops between steps) when that still fits.

    Returns:
        A :class:`WallMotion` in the same time base as ``times``: ``static``, ``rotation``
        (axis with its largest component positive, ``omega`` signed by the right-hand rule,
        ``origin`` the axis point nearest the coordinate origin) or ``translation``, starting
        where the poses start to change and stopping where they stop (None if they never do).

    Raises:
        MotionFitError: the poses are not one constant rotation or translation (a motion that
            stops and restarts, accelerates, or combines rotation and translation), or too few
            of them change to fit one.
    """
    times = np.asarray(times, np.float64)
    reference = np.asarray(reference, np.float64)
    moved = np.array(
        [
            np.abs(b.apply(reference) - a.apply(reference)).max()
            for a, b in itertools.pairwise(poses)
        ]
    )
    moving = np.flatnonzero(moved > 2 * tolerance)
    if not len(moving):
        return WallMotion("static")
    first, last = int(moving[0]), int(moving[-1])
    if len(moving) != last - first + 1:
        rest = int(np.setdiff1d(np.arange(first, last + 1), moving)[0])
        raise MotionFitError(
            f"it rests between t = {times[rest]:.6g} s and {times[rest + 1]:.6g} s but moves "
            "before and after: a motion that stops and restarts is not one WallMotion"
        )
    centre = reference.mean(0)
    spin = max(float(np.abs((p.rot - np.eye(3)) @ (reference - centre).T).max()) for p in poses)
    if spin <= tolerance:
        kind, values, extra = "translation", np.array([p.shift for p in poses]), {}
    else:
        kind = "rotation"
        axis, angles = _axis_and_angles(poses)
        origin = _rotation_origin(poses, angles, axis)
        values, extra = angles[:, None], {"axis": axis, "origin": origin}
    candidates = []
    for keep_start in (True, False):
        for keep_stop in (True, False):
            lo = first if keep_start else first + 1
            hi = last + 1 if keep_stop else last
            if hi - lo + 1 >= 2:
                candidates.append((lo, hi))
    worst = math.inf
    for lo, hi in candidates:
        motion = _ramp_motion(kind, times, values, lo, hi, first, last, extra)
        if motion is None:
            continue
        for snapped in _snapped(motion, dem_dt):
            deviation = _worst_deviation(snapped, times, poses, reference)
            if deviation <= tolerance:
                return snapped
            worst = min(worst, deviation)
    if len(moving) < 2:
        raise MotionFitError(
            f"it moves between only two dump frames (t = {times[first]:.6g} and "
            f"{times[first + 1]:.6g} s): too few to fit a motion; dump the meshes more often"
        )
    raise MotionFitError(
        f"no constant {kind} reproduces its poses (the best fit misses by {worst:.3g} m, more "
        f"than {tolerance:.3g} m): it accelerates, wiggles or combines motions; per-frame "
        "poses are not supported"
    )


def _axis_and_angles(poses: list[Pose]) -> tuple[np.ndarray, np.ndarray]:
    """A common unit axis ``[3]`` (largest component positive) and the unwrapped signed angles
    ``[K]`` (rad) of the poses' rotations about it."""
    weighted = np.zeros(3)
    for pose in poses:
        vals, vecs = np.linalg.eig(pose.rot)
        k = int(np.argmin(np.abs(vals - 1.0)))
        axis = np.real(vecs[:, k])
        axis /= np.linalg.norm(axis)
        weight = 3.0 - float(np.trace(pose.rot))  # 2 (1 - cos angle)
        if weighted @ axis < 0:
            axis = -axis
        weighted += weight * axis
    axis = weighted / np.linalg.norm(weighted)
    if axis[np.argmax(np.abs(axis))] < 0:
        axis = -axis
    angles = []
    for pose in poses:
        r = pose.rot
        w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
        angles.append(math.atan2(float(w @ axis), 0.5 * (float(np.trace(r)) - 1.0)))
    return axis, np.unwrap(np.array(angles))


def _rotation_origin(poses: list[Pose], angles: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """``[3]`` the point of the rotation axis nearest the coordinate origin: the least-squares
    fixed point of the poses, ``(I - rot) o = shift``, solved in the plane normal to
    ``axis`` (along it ``I - rot`` is singular)."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    plane = np.stack([e1, np.cross(axis, e1)], axis=1)  # [3, 2]
    rows = [
        ((np.eye(3) - p.rot) @ plane, p.shift)
        for p, a in zip(poses, angles, strict=True)
        if abs(a) > 1e-9
    ]
    a = np.concatenate([r for r, _ in rows])
    b = np.concatenate([s for _, s in rows])
    return plane @ np.linalg.lstsq(a, b, rcond=None)[0]


def _ramp_motion(
    kind: str,
    times: np.ndarray,
    values: np.ndarray,
    lo: int,
    hi: int,
    first: int,
    last: int,
    extra: dict,
) -> WallMotion | None:
    """The motion whose displacement ``values [K, D]`` (angles or shifts) is the straight line
    through frames ``lo..hi``, zero before its start and frozen after its stop."""
    t = times[lo : hi + 1]
    design = np.stack([t, np.ones_like(t)], 1)
    (rate, offset), *_ = np.linalg.lstsq(design, values[lo : hi + 1], rcond=None)
    speed = float(rate @ rate)
    if speed == 0.0:
        return None
    start = float(-(offset @ rate) / speed)  # where the line leaves zero
    stop = None
    if last + 2 < len(times):  # frames after the last moving interval: frozen there
        stop = float(((values[last + 1] - offset) @ rate) / speed)
    start = max(start, 0.0)
    if stop is not None and stop <= start:
        return None
    if kind == "rotation":
        return WallMotion(
            "rotation",
            axis=tuple(extra["axis"]),
            origin=tuple(extra["origin"]),
            omega=float(rate[0]),
            start_time=start,
            stop_time=stop,
        )
    return WallMotion("translation", velocity=tuple(rate), start_time=start, stop_time=stop)


def _snapped(motion: WallMotion, dem_dt: float | None) -> list[WallMotion]:
    """``motion`` with round numbers where they still fit (tried first), then as fitted: start
    and stop on DEM steps, axis and origin components below round-off set to zero."""
    changes: dict = {}
    if dem_dt:
        changes["start_time"] = round(motion.start_time / dem_dt) * dem_dt
        if motion.stop_time is not None:
            changes["stop_time"] = round(motion.stop_time / dem_dt) * dem_dt
    if motion.kind == "rotation":
        axis = np.where(np.abs(motion.axis) < 1e-6, 0.0, motion.axis)
        changes["axis"] = tuple(axis / np.linalg.norm(axis))
        changes["origin"] = tuple(np.where(np.abs(motion.origin) < 1e-7, 0.0, motion.origin))
    if motion.kind == "translation":
        changes["velocity"] = tuple(np.where(np.abs(motion.velocity) < 1e-9, 0.0, motion.velocity))
    out = []
    with contextlib.suppress(ValueError):  # e.g. a snapped stop no longer after the start
        out.append(replace(motion, **changes))
    out.append(motion)
    return out


def _worst_deviation(
    motion: WallMotion, times: np.ndarray, poses: list[Pose], reference: np.ndarray
) -> float:
    """Largest coordinate deviation (m) between ``motion`` and ``poses`` over ``reference``."""
    worst = 0.0
    for t, pose in zip(times, poses, strict=True):
        rot, shift = motion.pose(float(t))
        worst = max(worst, pose_deviation(reference, pose.apply(reference), Pose(rot, shift)))
    return worst
