"""Earth mover's distance between particle sets, exactly as the paper's evaluation (POT)."""

from __future__ import annotations

import numpy as np
import ot
from scipy.spatial.distance import cdist

from granular_pyg.errors import InputError

__all__ = ["emd", "emd_at_powers"]


def emd(a: np.ndarray, b: np.ndarray, squared: bool = True) -> float:
    r"""Optimal-transport distance between two particle sets with uniform weights.

    With ``squared=True`` (the paper's code: ``ot.emd2`` on ``ot.dist``, whose default metric is
    the squared Euclidean distance) this is :math:`W_2^2` in m^2; with ``squared=False`` the cost
    is the Euclidean distance and the result :math:`W_1` in m. Rows with NaN (particles that
    have left) are dropped from each set.

    Args:
        a: ``[N, 3]`` positions (m).
        b: ``[M, 3]`` positions (m).
        squared: squared Euclidean cost (W2^2) or Euclidean (W1).

    Returns:
        The distance (m^2 or m); 0 when both sets are empty.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"emd: expected [N, d] and [M, d] arrays, got {a.shape} and {b.shape}")
    a, b = a[np.isfinite(a).all(1)], b[np.isfinite(b).all(1)]
    if len(a) == 0 and len(b) == 0:
        return 0.0
    if len(a) == 0 or len(b) == 0:
        raise InputError(f"emd: one set is empty ({len(a)} against {len(b)} particles)")
    # The paper's cost for W2^2; cdist for W1 (ot.dist's expanded form loses digits under sqrt).
    cost = ot.dist(a, b) if squared else cdist(a, b)
    return float(
        ot.emd2(np.full(len(a), 1 / len(a)), np.full(len(b), 1 / len(b)), cost, numItermax=10**7)
    )


def emd_at_powers(
    truth: np.ndarray, pred: np.ndarray, squared: bool = True, max_power: int = 16
) -> dict[int, float]:
    """EMD at frames ``2^0, 2^1, ..., 2^k`` while both trajectories have them (the paper's table).

    Frame 0 is the last shared initial state, so frame ``2^j`` is the ``2^j``-th predicted step.
    A frame where either set is empty (a hopper that has drained in one but not the other) has
    no EMD and is left out.

    Args:
        truth: ``[T, N, 3]`` positions (m), NaN once a particle has left.
        pred: ``[T', M, 3]`` positions (m).
        squared: W2^2 (the paper) or W1, see :func:`emd`.
        max_power: largest ``k`` considered (the paper: 16).

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
        a, b = truth[step], pred[step]
        if np.isfinite(a).all(1).any() and np.isfinite(b).all(1).any():
            out[step] = emd(a, b, squared=squared)
    return out
