"""Earth mover's distance between particle sets, exactly as the paper's evaluation (POT).

Particles that have left a hopper (NaN rows) are not in either set, so late in a discharge one
side can be empty while the other is not: a rollout that drains too fast. Rather than leave such
frames out (which would score a model that drains too fast better), :func:`emd` can stand the
empty side in by one point, ``sink``: where its particles went, the outlet below which they
left (:func:`outlet_point`). The cost of the frame is then that of moving every remaining
particle of the other side to the outlet, the distance the paper's EMD gives against a single
particle left there, so a frame near the end of a discharge costs little, a full bed against an
empty hopper much. Two empty sets are equal (0).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist

from granular_pyg.errors import InputError
from granular_pyg.scenes import Scene

__all__ = ["MAX_EMD_POINTS", "emd", "emd_at_powers", "outlet_point"]

#: Largest set :func:`emd` solves exactly: the cost matrix of two 4,000-point sets is 128 MB
#: and POT solves it in seconds; that of two 20,000-point sets would be 3.2 GB and take hours.
MAX_EMD_POINTS = 4000


def outlet_point(scene: Scene) -> np.ndarray:
    """``[3]`` (m) where the particles that leave ``scene`` go, the stand-in for them in
    :func:`emd`: on the outflow plane (the simulation box's floor for a closed scene), below the
    centroid of the removable walls' vertices (the lid over the outlet), or below the box's
    centre when no wall is removable."""
    lids = [w.vertices_at(0.0) for w in scene.walls if w.removal_time is not None]
    if lids:
        x, y = np.concatenate(lids).mean(0)[:2]
    else:
        x, y = (0.5 * (np.asarray(scene.domain_lo) + np.asarray(scene.domain_hi)))[:2]
    z = scene.outflow_z if scene.outflow_z is not None else scene.domain_lo[2]
    return np.array([x, y, z], dtype=np.float64)


def _present(name: str, points: np.ndarray) -> np.ndarray:
    """The rows of ``points [N, d]`` without NaN; rows with NaN in only some coordinates are
    refused (a corrupted particle, not one that left)."""
    finite = np.isfinite(points)
    partial = finite.any(1) & ~finite.all(1)
    if partial.any():
        rows = np.flatnonzero(partial)
        raise InputError(
            f"emd: {name} has {len(rows)} row(s) with NaN/Inf in only some coordinates (first: "
            f"row {rows[0]}, {points[rows[0]].tolist()}); a particle that left is NaN in every "
            "coordinate"
        )
    return points[finite.all(1)]


def _subsample(a: np.ndarray, b: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_points`` rows of each set, drawn without replacement with a fixed seed;
    two sets of the same length (the same particles, truth and prediction) keep the same rows,
    so a perfect prediction still scores 0."""
    rng = np.random.default_rng(0)
    if len(a) == len(b) and len(a) > max_points:
        rows = np.sort(rng.choice(len(a), max_points, replace=False))
        return a[rows], b[rows]
    if len(a) > max_points:
        a = a[np.sort(rng.choice(len(a), max_points, replace=False))]
    if len(b) > max_points:
        b = b[np.sort(rng.choice(len(b), max_points, replace=False))]
    return a, b


def emd(
    a: np.ndarray,
    b: np.ndarray,
    squared: bool = True,
    sink: np.ndarray | None = None,
    max_points: int | None = MAX_EMD_POINTS,
) -> float:
    r"""Optimal-transport distance between two particle sets with uniform weights.

    With ``squared=True`` (the paper's code: ``ot.emd2`` on ``ot.dist``, whose default metric is
    the squared Euclidean distance) this is :math:`W_2^2` in m^2; with ``squared=False`` the cost
    is the Euclidean distance and the result :math:`W_1` in m. Rows that are NaN in every
    coordinate (particles that have left) are dropped from each set.

    When one set is empty and the other is not, the empty set is the single point ``sink``
    (where its particles went, :func:`outlet_point`): the result is the mean over the other
    set of the (squared) distance to ``sink`` (see the module docstring).

    Args:
        a: ``[N, 3]`` positions (m).
        b: ``[M, 3]`` positions (m).
        squared: squared Euclidean cost (W2^2) or Euclidean (W1).
        sink: ``[3]`` (m) the point that stands in for an empty set, or None.
        max_points: above this many particles in a set, the distance is that of a random
            subset of the particles (fixed seed; the same rows of both sets when they are the
            same particles, before the particles that left are dropped); None: always exact.

    Returns:
        The distance (m^2 or m); 0 when both sets are empty.

    Raises:
        InputError: on bad shapes, on rows with NaN/Inf in only some coordinates, and when one
            set is empty without a ``sink``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"emd: expected [N, d] and [M, d] arrays, got {a.shape} and {b.shape}")
    if max_points is not None and max(len(a), len(b)) > max_points:
        _present("a", a), _present("b", b)  # refuse a corrupted row even if it is not drawn
        a, b = _subsample(a, b, int(max_points))
    a, b = _present("a", a), _present("b", b)
    if len(a) == 0 and len(b) == 0:
        return 0.0
    if len(a) == 0 or len(b) == 0:
        if sink is None:
            raise InputError(
                f"emd: one set is empty ({len(a)} against {len(b)} particles); pass sink (the "
                "outlet point, metrics.outlet_point(scene)) to stand in for the particles "
                "that left"
            )
        sink = np.asarray(sink, dtype=np.float64).reshape(1, -1)
        if sink.shape[1] != a.shape[1] or not np.isfinite(sink).all():
            raise InputError(f"sink: expected {a.shape[1]} finite coordinates, got {sink}")
        a, b = (sink, b) if len(a) == 0 else (a, sink)
    import ot  # POT, imported on first use: a command that scores no EMD runs without it

    # The paper's cost for W2^2; cdist for W1 (ot.dist's expanded form loses digits under sqrt).
    cost = ot.dist(a, b) if squared else cdist(a, b)
    return float(
        ot.emd2(np.full(len(a), 1 / len(a)), np.full(len(b), 1 / len(b)), cost, numItermax=10**7)
    )


def emd_at_powers(
    truth: np.ndarray,
    pred: np.ndarray,
    squared: bool = True,
    max_power: int = 16,
    sink: np.ndarray | None = None,
) -> dict[int, float]:
    """EMD at frames ``2^0, 2^1, ..., 2^k`` while both trajectories have them (the paper's table).

    Frame 0 is the last shared initial state, so frame ``2^j`` is the ``2^j``-th predicted step.
    No frame is left out: every model of a trajectory gets the same frames. A frame where one
    side has drained and the other has not costs the move of the remaining particles to
    ``sink`` (:func:`emd`); one where both have drained costs 0.

    Args:
        truth: ``[T, N, 3]`` positions (m), NaN once a particle has left.
        pred: ``[T', M, 3]`` positions (m).
        squared: W2^2 (the paper) or W1, see :func:`emd`.
        max_power: largest ``k`` considered (the paper: 16).
        sink: ``[3]`` (m) the outlet point (:func:`outlet_point`); without it a frame where
            only one side has drained raises InputError.

    Returns:
        ``{2^j: distance}`` in increasing order; empty if neither has frame 1.
    """
    if truth.ndim != 3 or pred.ndim != 3:
        raise InputError(
            f"emd_at_powers: expected [T, N, 3] arrays, got {truth.shape}, {pred.shape}"
        )
    frames = min(len(truth), len(pred))
    out: dict[int, float] = {}
    for j in range(max_power + 1):
        step = 2**j
        if step >= frames:
            break
        out[step] = emd(truth[step], pred[step], squared=squared, sink=sink)
    return out
