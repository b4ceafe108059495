"""Brute-force references for the geometry tests (deliberately simple, float64, loops allowed)."""

from __future__ import annotations

import numpy as np


def closest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    dd = float(d @ d)
    u = 0.0 if dd == 0.0 else min(max(float((p - a) @ d) / dd, 0.0), 1.0)
    return a + u * d


def closest_on_triangle(p: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, float]:
    """Minimum over the three edge projections and, when it falls inside, the plane projection."""
    v0, v1, v2 = tri
    candidates = [
        closest_on_segment(p, v0, v1),
        closest_on_segment(p, v0, v2),
        closest_on_segment(p, v1, v2),
    ]
    n = np.cross(v1 - v0, v2 - v0)
    nn = float(n @ n)
    if nn > 0.0:
        q = p - (float((p - v0) @ n) / nn) * n
        # Barycentric inside test with signed areas.
        inside = all(
            float(np.cross(b - a, q - a) @ n) >= 0.0 for a, b in ((v0, v1), (v1, v2), (v2, v0))
        )
        if inside:
            candidates.append(q)
    sq = [float((c - p) @ (c - p)) for c in candidates]
    best = int(np.argmin(sq))
    return candidates[best], sq[best]
