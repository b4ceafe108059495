"""Flow observables on positions ``[T, N, 3]`` (m): mixing, flow profiles, discharge.

Every function is pure NumPy and takes NaN rows as particles that have left the scene. Leaked
particles (through the Scene's walls) are in :mod:`granular_pyg.metrics.leaks`.
"""

from __future__ import annotations

import numpy as np

from granular_pyg.errors import InputError

__all__ = [
    "bed_mass",
    "discharge_curve",
    "discharge_rate",
    "flow_profile",
    "mixing_classes",
    "mixing_entropy",
    "mixing_entropy_curve",
    "position_mse",
    "time_to_empty",
]


def _check_positions(name: str, positions: np.ndarray, ndim: int = 3) -> np.ndarray:
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != ndim or positions.shape[-1] != 3:
        want = "[T, N, 3]" if ndim == 3 else "[N, 3]"
        raise InputError(f"{name}: expected positions {want}, got shape {list(positions.shape)}")
    return positions


def position_mse(truth: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """``[T]`` mean squared position error (m^2) over the particles present in both, NaN if none."""
    truth, pred = _check_positions("truth", truth), _check_positions("pred", pred)
    if truth.shape != pred.shape:
        raise InputError(f"pred: shape {pred.shape} differs from the truth's {truth.shape}")
    both = np.isfinite(truth).all(-1) & np.isfinite(pred).all(-1)
    sq = np.where(both, ((truth - pred) ** 2).sum(-1) / 3.0, 0.0)
    count = both.sum(1)
    return np.where(count > 0, sq.sum(1) / np.maximum(count, 1), np.nan)


def mixing_classes(positions: np.ndarray, frame: int = 30, axis=2) -> np.ndarray:
    """The paper's two mixing classes: ``+1`` above, ``-1`` below the median of one coordinate.

    Args:
        positions: ``[T, N, 3]`` (m).
        frame: the frame ``t0`` at which the classes are fixed (paper: 30).
        axis: the coordinate that splits them (0 = x, 2 = z), or a direction ``[3]`` (the
            positions' component along it, e.g. across a drum's axis in any frame).

    Returns:
        ``[N]`` int8 in ``{+1, -1}``, 0 for particles absent at ``frame``.
    """
    positions = _check_positions("positions", positions)
    if not 0 <= frame < len(positions):
        raise InputError(f"frame: {frame} is outside the trajectory's {len(positions)} frames")
    if np.ndim(axis) == 0:
        coord = positions[frame, :, int(axis)]
    else:
        coord = positions[frame] @ np.asarray(axis, np.float64).reshape(3)
    present = np.isfinite(coord)
    if not present.any():
        raise InputError(f"positions: no particle is present at frame {frame}")
    threshold = np.median(coord[present])
    classes = np.where(coord > threshold, 1, -1).astype(np.int8)
    classes[~present] = 0
    return classes


def mixing_entropy(positions: np.ndarray, classes: np.ndarray, bins: int = 9) -> float:
    r"""The paper's mixing entropy (appendix) of one frame, 0 (segregated) to log 2 (mixed).

    The particles' bounding box is cut into ``bins^3`` cells (in the frame of the bed's
    horizontal principal axes and z, so that turning or mirroring the scene about gravity
    does not change the cells); with :math:`f_\pm` the fraction of
    each class in a cell, :math:`s = -f_+ \log f_+ - f_- \log f_-` and
    :math:`S = \sum n_{cell} s_{cell} / \sum n_{cell}` (natural log, ``0 log 0 = 0``).

    Args:
        positions: ``[N, 3]`` (m); NaN rows and class-0 particles are left out.
        classes: ``[N]`` in ``{+1, -1, 0}`` from :func:`mixing_classes`.
        bins: cells per axis (paper: 9).

    Returns:
        ``S`` (nats), NaN when no classified particle is present.
    """
    positions = _check_positions("positions", positions, ndim=2)
    classes = np.asarray(classes)
    if classes.shape != positions.shape[:1]:
        raise InputError(f"classes: expected shape [{len(positions)}], got {list(classes.shape)}")
    keep = np.isfinite(positions).all(1) & (classes != 0)
    pos, cls = positions[keep], classes[keep]
    if len(pos) == 0:
        return float("nan")
    pos = _in_principal_frame(pos)
    lo, hi = pos.min(0), pos.max(0)
    span = np.where(hi > lo, hi - lo, 1.0)
    cell = np.clip(((pos - lo) / span * bins).astype(np.int64), 0, bins - 1)
    flat = (cell[:, 0] * bins + cell[:, 1]) * bins + cell[:, 2]
    plus = np.bincount(flat[cls > 0], minlength=bins**3).astype(np.float64)
    minus = np.bincount(flat[cls < 0], minlength=bins**3).astype(np.float64)
    n = plus + minus
    occupied = n > 0
    f_plus, f_minus = plus[occupied] / n[occupied], minus[occupied] / n[occupied]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -np.nan_to_num(f_plus * np.log(f_plus)) - np.nan_to_num(f_minus * np.log(f_minus))
    return float((n[occupied] * s).sum() / n[occupied].sum())


def _in_principal_frame(pos: np.ndarray) -> np.ndarray:
    """``[N, 3]`` coordinates along the horizontal principal axes of ``pos`` (larger spread
    first, each axis signed so that its third moment is >= 0), then z: the same numbers for
    the bed turned about z or mirrored (unless its two horizontal spreads are equal)."""
    h = pos[:, :2] - pos[:, :2].mean(0)
    _, vectors = np.linalg.eigh(h.T @ h)
    coords = h @ vectors[:, ::-1]
    signs = np.where((coords**3).sum(0) < 0, -1.0, 1.0)
    return np.column_stack([coords * signs, pos[:, 2]])


def mixing_entropy_curve(positions: np.ndarray, classes: np.ndarray, bins: int = 9) -> np.ndarray:
    """``[T]`` :func:`mixing_entropy` of every frame."""
    positions = _check_positions("positions", positions)
    return np.array([mixing_entropy(frame, classes, bins) for frame in positions])


def flow_profile(
    positions: np.ndarray,
    velocities: np.ndarray,
    z_bins: int = 19,
    z_range: tuple[float, float] | None = None,
    component: int = 2,
) -> np.ndarray:
    """Mean velocity per height bin and frame (the paper's flow profiles).

    Args:
        positions: ``[T, N, 3]`` (m).
        velocities: ``[T, N, 3]`` (m/s).
        z_bins: number of bins in z (paper: 19).
        z_range: ``(lo, hi)`` (m); default the range of all finite z.
        component: velocity component averaged (2 = vertical).

    Returns:
        ``[T, z_bins]`` mean velocity (m/s), NaN in empty bins.
    """
    positions = _check_positions("positions", positions)
    velocities = _check_positions("velocities", velocities)
    if velocities.shape != positions.shape:
        raise InputError(f"velocities: shape {velocities.shape} differs from {positions.shape}")
    z, v = positions[..., 2], velocities[..., component]
    ok = np.isfinite(z) & np.isfinite(v)
    if z_range is None:
        if not ok.any():
            raise InputError("positions: no finite particle to bin")
        z_range = (float(z[ok].min()), float(z[ok].max()))
    lo, hi = z_range
    width = (hi - lo) / z_bins if hi > lo else 1.0
    which = np.clip(np.floor((np.where(ok, z, lo) - lo) / width), 0, z_bins - 1).astype(np.int64)
    which = which + z_bins * np.arange(len(z))[:, None]
    total = np.bincount(which[ok], weights=v[ok], minlength=len(z) * z_bins)
    count = np.bincount(which[ok], minlength=len(z) * z_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (total / count).reshape(len(z), z_bins)


def discharge_curve(positions: np.ndarray, outlet_z: float, mass: np.ndarray) -> np.ndarray:
    """``[T]`` mass (kg) of the initial bed that has left: below ``outlet_z`` or gone.

    The initial bed is the particles present above the outlet in the first frame; a particle
    already below it (or absent) then is not part of the bed and never counts. Only heights
    enter, so turning the scene about the vertical or mirroring it changes nothing.

    Args:
        positions: ``[T, N, 3]`` (m), NaN once gone.
        outlet_z: outlet height (m).
        mass: ``[N]`` particle masses (kg).
    """
    positions = _check_positions("positions", positions)
    mass = np.asarray(mass, dtype=np.float64)
    if mass.shape != positions.shape[1:2]:
        raise InputError(f"mass: expected shape [{positions.shape[1]}], got {list(mass.shape)}")
    z = positions[..., 2]
    bed = np.isfinite(z[0]) & (np.nan_to_num(z[0], nan=-np.inf) >= outlet_z)
    out = ~(np.nan_to_num(z, nan=-np.inf) >= outlet_z)  # below the outlet or gone
    return (out & bed) @ np.where(bed, mass, 0.0)


def bed_mass(positions: np.ndarray, outlet_z: float, mass: np.ndarray) -> float:
    """Mass (kg) of the initial bed: the particles above ``outlet_z`` in the first frame of
    ``positions [T, N, 3]`` (m); ``mass [N]`` (kg)."""
    z = _check_positions("positions", positions)[0, :, 2]
    bed = np.isfinite(z) & (np.nan_to_num(z, nan=-np.inf) >= outlet_z)
    return float(np.asarray(mass, dtype=np.float64)[bed].sum())


def discharge_rate(
    times: np.ndarray,
    positions: np.ndarray,
    outlet_z: float,
    mass: np.ndarray,
    window: tuple[float, float] = (0.2, 0.8),
    first_frame: int = 0,
) -> tuple[float, tuple[float, float]]:
    """Mass flow rate (kg/s) through the outlet: a line fitted to the discharged mass of the
    initial bed (:func:`discharge_curve`).

    The fit spans the frames from the first at which ``window[0]`` of the *initial bed's* mass
    has left to the first at which ``window[1]`` has (the steady, Beverloo part, without the
    start-up and the last particles). Both sides of a comparison are measured against their
    own initial bed, which is the same bed, not against the mass each finally let out: a
    rollout that stops with part of its bed inside never reaches ``window[1]``, and its fit
    then runs on to its last frame, so the stall lowers its rate instead of being cut off.

    With fewer than three frames in the window (a rollout whose learned steps are coarse
    against a fast drain), the rate is the mean one between the window's bounds, their
    crossing times read off the curve joined linearly between frames.

    Args:
        times: ``[T]`` (s).
        positions: ``[T, N, 3]`` (m), NaN once gone.
        outlet_z: outlet height (m).
        mass: ``[N]`` particle masses (kg).
        window: fractions of the initial bed's mass that bound the fit.
        first_frame: frames before it are left out of the fit (a rollout's copied initial
            states: a window that ends among them is no measure of the model); the bed is
            still that of frame 0.

    Returns:
        ``(rate kg/s, (t_start, t_end) s)`` of the fit.

    Raises:
        InputError: an empty bed, or a window not crossed after ``first_frame`` (too little
            discharge).
    """
    positions = _check_positions("positions", positions)
    times = np.asarray(times, dtype=np.float64)
    if times.shape != positions.shape[:1]:
        raise InputError(f"times: expected shape [{len(positions)}], got {list(times.shape)}")
    discharged = discharge_curve(positions, outlet_z, mass)
    bed = bed_mass(positions, outlet_z, mass)
    lo, hi = window[0] * bed, window[1] * bed
    started = np.flatnonzero(discharged >= lo) if bed > 0 else np.array([], dtype=int)
    ended = np.flatnonzero(discharged >= hi)
    first = max(int(started[0]), int(first_frame)) if started.size else len(times)
    last = int(ended[0]) if ended.size else len(times) - 1
    if last - first + 1 >= 3:
        t, m = times[first : last + 1], discharged[first : last + 1]
        return float(np.polyfit(t, m, 1)[0]), (float(t[0]), float(t[-1]))
    # Too few frames for a fit (a bed that drains within a few coarse frames, such as a
    # learned rollout's): the mean rate between the window's bounds, crossed on the curve
    # joined linearly between frames; a fast drain must not drop out as "no rate".
    start = int(first_frame)
    if bed > 0 and start < len(times) - 1 and discharged[start] < hi and discharged[-1] > lo:
        t0, m0 = _crossing(times, discharged, lo, start)
        t1, m1 = _crossing(times, discharged, hi, start)
        if t1 > t0:
            return float((m1 - m0) / (t1 - t0)), (t0, t1)
    raise InputError(
        "positions: too little discharge for a flow rate (fewer than 3 frames between "
        f"{window[0]:.0%} and {window[1]:.0%} of the initial bed's mass); roll out longer"
    )


def _crossing(
    times: np.ndarray, curve: np.ndarray, level: float, start: int
) -> tuple[float, float]:
    """``(time s, mass kg)`` where the non-decreasing ``curve [T]``, joined linearly between
    frames from frame ``start`` on, first reaches ``level``: its first point when it starts
    above, its last point when it never reaches it."""
    reached = np.flatnonzero(curve[start:] >= level)
    if not reached.size:
        return float(times[-1]), float(curve[-1])
    j = start + int(reached[0])
    if j == start:
        return float(times[j]), float(curve[j])
    f = (level - curve[j - 1]) / (curve[j] - curve[j - 1])
    return float(times[j - 1] + f * (times[j] - times[j - 1])), float(level)


def time_to_empty(
    times: np.ndarray,
    positions: np.ndarray,
    outlet_z: float,
    mass: np.ndarray,
    level: float = 0.99,
    since: float = 0.0,
) -> float:
    """Time (s) from ``since`` (the outlet's opening) until ``level`` of the initial bed's mass
    has left (:func:`discharge_curve`); NaN when it never does within ``times``.

    Args:
        times: ``[T]`` (s).
        positions: ``[T, N, 3]`` (m), NaN once gone.
        outlet_z: outlet height (m).
        mass: ``[N]`` particle masses (kg).
        level: the fraction of the initial bed that counts as empty (default 99%: a few
            particles left on a ledge do not keep a hopper from being empty).
        since: recorded time (s) the clock starts from.
    """
    if not 0.0 < level <= 1.0:
        raise InputError(f"level: expected a fraction in (0, 1], got {level}")
    times = np.asarray(times, dtype=np.float64)
    bed = bed_mass(positions, outlet_z, mass)
    if bed <= 0:
        return float("nan")
    done = np.flatnonzero(discharge_curve(positions, outlet_z, mass) >= level * bed * (1 - 1e-12))
    return float(times[done[0]] - since) if done.size else float("nan")
