"""LIGGGHTS's angle check on a wall's triangles, made before LIGGGHTS starts.

LIGGGHTS refuses a mesh with a triangle whose smallest angle is at or below
:data:`MIN_ANGLE_DEG`; a Scene's walls are checked here so that the refusal comes first, with
the wall, triangle and angle named (the LIGGGHTS runner, ``dem/liggghts.py``, and the example
meshes both use it).
"""

from __future__ import annotations

import numpy as np

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import Wall

__all__ = ["MIN_ANGLE_DEG", "check_wall_for_liggghts", "min_angles_deg"]

#: LIGGGHTS rejects triangles with an angle at or below this (degrees).
MIN_ANGLE_DEG = 0.256


def min_angles_deg(triangles: np.ndarray) -> np.ndarray:
    """``[F]`` smallest interior angle of each triangle (deg); 0 for degenerate ones."""
    angles = []
    for i in range(3):
        a, b, c = triangles[:, i], triangles[:, (i + 1) % 3], triangles[:, (i + 2) % 3]
        u, v = b - a, c - a
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        cos = np.einsum("ij,ij->i", u, v) / np.maximum(nu * nv, np.finfo(float).tiny)
        ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        angles.append(np.where((nu > 0) & (nv > 0), ang, 0.0))
    return np.min(angles, axis=0)


def check_wall_for_liggghts(wall: Wall) -> None:
    """Raise :class:`InputError` (before LIGGGHTS starts) if a triangle would fail its angle
    check (every angle must exceed 0.256 deg), naming the wall, triangle and angle."""
    angles = min_angles_deg(wall.triangles)
    bad = np.flatnonzero(angles <= MIN_ANGLE_DEG)
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"wall {wall.name}: {bad.size} triangle(s) have an angle <= {MIN_ANGLE_DEG} deg, "
            f"which LIGGGHTS rejects (first: triangle {i}, vertices {wall.faces[i].tolist()}, "
            f"angle {angles[i]:.3g} deg); remesh the wall or merge the sliver triangles"
        )
