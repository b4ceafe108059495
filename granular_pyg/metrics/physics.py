"""Physical observables engineers check: discharge, centre of mass, dynamic angle of repose,
crushed particles; and what a Scene's kind says about them (the hopper's outlet height, the
drum's axis)."""

from __future__ import annotations

import math

import numpy as np

from granular_pyg.errors import InputError
from granular_pyg.scenes import Scene

__all__ = [
    "across_drum_axis",
    "centre_of_mass",
    "centre_of_mass_swing",
    "crushed_particles",
    "discharged_fraction",
    "drum_axis",
    "dynamic_angle_of_repose",
    "outlet_height",
]


def outlet_height(scene: Scene) -> float:
    """Height (m) of a hopper's outlet: ``params["outlet_z"]``, 0 when absent (the built-in
    hopper puts its outlet at z = 0; a mesh scene stores its own)."""
    return float(scene.params.get("outlet_z", 0.0))


def drum_axis(scene: Scene) -> np.ndarray | None:
    """Unit vector ``[3]`` of the horizontal axis a drum turns about: the first rotating wall's
    ``motion.axis`` with its vertical part dropped (any horizontal direction: the scene's frame
    does not matter); None when no wall rotates or the axis is closer to vertical than to
    horizontal (no free surface across it). Its sign is the axis's, which the angle of repose
    does not use."""
    for wall in scene.walls:
        motion = wall.motion
        if motion.kind == "rotation" and motion.omega != 0.0:
            axis = np.asarray(motion.axis, dtype=np.float64)
            horizontal = np.array([axis[0], axis[1], 0.0])
            length = float(np.linalg.norm(horizontal))
            if length <= abs(axis[2]):
                return None
            return horizontal / length
    return None


def across_drum_axis(axis) -> np.ndarray:
    """Unit horizontal vector ``[3]`` orthogonal to a drum's horizontal ``axis`` (an index 0 = x,
    1 = y, or a vector): the direction the free surface slopes along."""
    a = _axis_vector(axis)
    return np.array([-a[1], a[0], 0.0])


def _axis_vector(axis) -> np.ndarray:
    if isinstance(axis, (int, np.integer)):
        if axis not in (0, 1):
            raise InputError(f"axis: the drum axis must be horizontal (0 = x or 1 = y), got {axis}")
        return np.eye(3)[int(axis)]
    a = np.asarray(axis, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"axis: expected 0, 1 or a horizontal vector [3], got {axis!r}")
    horizontal = np.array([a[0], a[1], 0.0])
    length = float(np.linalg.norm(horizontal))
    if length == 0.0 or length < 0.999 * float(np.linalg.norm(a)):
        raise InputError(f"axis: the drum axis must be horizontal, got {a.tolist()}")
    return horizontal / length


def discharged_fraction(positions: np.ndarray, outlet_z: float = 0.0) -> np.ndarray:
    """Fraction of the particles below the outlet or gone (NaN), per frame.

    Args:
        positions: ``[T, N, 3]`` (m), NaN once a particle has left.
        outlet_z: height of the outlet (m).

    Returns:
        ``[T]`` values in ``[0, 1]``.
    """
    z = positions[..., 2]
    return np.mean(np.isnan(z) | (z < outlet_z), axis=1)


def centre_of_mass_swing(centres: np.ndarray, times: np.ndarray, after: float) -> float:
    """How far a bed's centre of mass swings once it should have settled: the largest distance
    (m) of the centre from its mean position over the frames at ``times >= after``.

    A drum's bed in steady rotation holds its centre still (LIGGGHTS: about a millimetre of
    jitter); a bed that rocks like a pendulum shows its amplitude here.

    Args:
        centres: ``[T, 3]`` centre of mass per frame (m), NaN rows where no particle is present.
        times: ``[T]`` (s).
        after: s, start of the settled part.

    Returns:
        The swing (m); NaN with fewer than two settled frames.
    """
    late = np.asarray(centres, dtype=np.float64)[np.asarray(times) >= after - 1e-9]
    late = late[np.isfinite(late).all(axis=1)]
    if len(late) < 2:
        return float("nan")
    return float(np.linalg.norm(late - late.mean(axis=0), axis=1).max())


def centre_of_mass(positions: np.ndarray) -> np.ndarray:
    """``[T, 3]`` mean position of the particles still present (equal masses), NaN if none."""
    present = np.isfinite(positions).all(-1, keepdims=True)
    count = present.sum(1)
    total = np.where(present, positions, 0.0).sum(1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def dynamic_angle_of_repose(
    positions: np.ndarray, axis=1, bins: int = 12, trim: float = 0.15
) -> float:
    """Slope (deg) of a drum's free surface: a line fitted to the top particle of each bin.

    Positions are projected onto the vertical plane orthogonal to the drum axis; the bed's
    extent across the axis (without ``trim`` of it at each end, where the surface curves along
    the wall) is cut into ``bins`` bins; the highest particle of each bin marks the surface.
    The result does not depend on the scene's frame: turning the drum about gravity, mirroring
    it, or turning it the other way gives the same angle.

    Args:
        positions: ``[N, 3]`` one frame (m); NaN rows are ignored.
        axis: the drum axis: 0 (x), 1 (y) or any horizontal vector ``[3]``
            (:func:`drum_axis`); gravity along -z.
        bins: surface bins.
        trim: fraction of the bed's width left out at each end.

    Returns:
        The angle between the fitted surface and the horizontal, in degrees (0-90).
    """
    across = across_drum_axis(axis)
    pos = positions[np.isfinite(positions).all(1)]
    if len(pos) < 2 * bins:
        raise InputError(f"positions: need at least {2 * bins} particles, got {len(pos)}")
    x, z = pos @ across, pos[:, 2]
    lo, hi = np.quantile(x, [trim, 1 - trim])
    edges = np.linspace(lo, hi, bins + 1)
    which = np.digitize(x, edges) - 1
    xs, zs = [], []
    for b in range(bins):
        inside = which == b
        if inside.any():
            top = np.argmax(np.where(inside, z, -np.inf))
            xs.append(x[top])
            zs.append(z[top])
    slope = np.polyfit(xs, zs, 1)[0]
    return math.degrees(math.atan(abs(slope)))


def crushed_particles(positions: np.ndarray, distance: float) -> np.ndarray:
    """Particles whose centre is closer than ``distance`` (m) to another's, per frame.

    With ``distance`` the smallest particle radius this counts particles overlapping a
    neighbour by more than half a diameter, which DEM never allows: a learned model that does
    not keep particles apart crushes its bed.

    Args:
        positions: ``[T, N, 3]`` (m), NaN once a particle has left.
        distance: centre distance (m), > 0.

    Returns:
        ``[T]`` int counts.
    """
    from scipy.spatial import cKDTree

    if not (math.isfinite(distance) and distance > 0):
        raise InputError(f"distance: expected a positive distance (m), got {distance}")
    counts = np.zeros(positions.shape[0], dtype=np.int64)
    for f, frame in enumerate(positions):
        present = frame[np.isfinite(frame).all(-1)].astype(np.float64)
        if len(present) > 1:
            pairs = cKDTree(present).query_pairs(distance, output_type="ndarray")
            gap = np.linalg.norm(present[pairs[:, 0]] - present[pairs[:, 1]], axis=1)
            counts[f] = np.unique(pairs[gap < distance]).size  # strictly closer
    return counts
