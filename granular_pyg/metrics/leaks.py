"""Leaked particles: centres that went through a Scene's real walls (its triangle meshes).

A particle's centre has leaked in frame ``f`` when

1. its move from frame ``f - 1`` to frame ``f`` crosses a triangle of a wall present at frame
   ``f``'s time, the start posed at ``f - 1``'s time and the end at ``f``'s (a centre carried
   along by a rotating drum never crosses it): the wall guard's test
   (:meth:`granular_pyg.scenes.WallSet.crossings`, without its skin). DEM never lets a centre
   cross a wall, so there is no tolerance: a move that ends on a wall's plane within one of its
   triangles, or past it, has leaked, whatever the particle's radius. Only the triangles near
   each move are tested (the wall index's candidates), in float64;
2. it lies outside the Scene's simulation box other than below its outflow floor (a particle
   flung out of the equipment);
3. in the particle's first frame (no move to test yet), its centre lies outside the walls
   present then: outside their closed surface when every edge is shared by two triangles (the
   drum, by ray parity), else outside their convex hull (an open-topped hopper or silo), except
   below the walls' lowest point in a scene with an outflow (falling towards it); see
   :func:`granular_pyg.scenes.containment.inside_walls`. A centre on the hull's surface (within
   round-off) is inside; walls that enclose no volume (a flat plate) are not tested.

A particle that falls below the outflow through an open outlet has not leaked; one that gets
there through a wall, or through the outlet while the lid (a wall with a removal time) is still
there, has (its move crosses the wall or the lid). Particles that have left (NaN rows) are not
tested, nor is the move of a particle that vanishes between two frames.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

from granular_pyg.errors import InputError
from granular_pyg.scenes import Scene, WallSet
from granular_pyg.scenes.containment import inside_closed_surface, is_closed_surface, walls_at

__all__ = ["leaked_mask", "leaked_particles"]

#: Relative round-off (of the walls' extent) on the first-frame convex-hull test.
_ROUND_OFF = 1e-9


def _check(positions: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[-1] != 3:
        raise InputError(f"positions: expected [T, N, 3], got shape {list(positions.shape)}")
    times = np.asarray(times, dtype=np.float64)
    if times.shape != positions.shape[:1]:
        raise InputError(f"times: expected shape [{len(positions)}], got {list(times.shape)}")
    return positions, times


def _outside_box(positions: np.ndarray, scene: Scene) -> np.ndarray:
    """``[..., N]`` bool: centres outside the simulation box, the outflow floor excepted."""
    with np.errstate(invalid="ignore"):
        out = (positions > np.asarray(scene.domain_hi)) | (positions < np.asarray(scene.domain_lo))
        if scene.outflow_z is not None:
            out[..., 2] = positions[..., 2] > scene.domain_hi[2]  # leaving through the floor
    return out.any(-1)


def _outside_walls(points: np.ndarray, scene: Scene, t: float) -> np.ndarray:
    """``[P]`` bool: points ``[P, 3]`` (m) outside the walls present at ``t`` (s) (the first-frame
    test of the module docstring); False where the walls enclose no volume."""
    triangles, _ = walls_at(scene, t)
    if len(triangles) == 0:
        return np.zeros(len(points), bool)
    if is_closed_surface(triangles):
        return ~inside_closed_surface(points, triangles)
    vertices = triangles.reshape(-1, 3)
    try:
        hull = ConvexHull(vertices)
    except QhullError:  # flat walls (a plate, a chute): no inside to test
        return np.zeros(len(points), bool)
    # On the hull's surface counts as inside: round-off in its planes decides nothing.
    slack = _ROUND_OFF * float(np.ptp(vertices, axis=0).max())
    outside = np.any(points @ hull.equations[:, :3].T + hull.equations[:, 3] > slack, axis=1)
    if scene.outflow_z is not None:
        outside &= points[:, 2] >= vertices[:, 2].min()  # below the walls: falling to the outflow
    return outside


def leaked_mask(
    positions: np.ndarray,
    scene: Scene,
    times: np.ndarray,
    *,
    walls: WallSet | None = None,
    initial: bool = True,
) -> np.ndarray:
    """``[T, N]`` bool: the frames in which each particle's centre leaked (module docstring).

    Args:
        positions: ``[T, N, 3]`` (m), NaN once a particle has left.
        scene: the Scene whose walls, box and outflow the particles were in.
        times: ``[T]`` recorded times (s) of the frames, which pose the walls and say which
            are present.
        walls: the Scene's :class:`~granular_pyg.scenes.WallSet`, to reuse its wall indices
            over many calls (built from ``scene`` when omitted).
        initial: test each particle's first frame against the walls (test 3 of the module
            docstring); a running check whose previous frame was tested already passes False.

    Returns:
        ``[T, N]`` bool; False for NaN rows.
    """
    positions, times = _check(positions, times)
    present = np.isfinite(positions).all(-1)
    mask = _outside_box(positions, scene) & present
    if initial:
        first = np.argmax(present, axis=0)
        seen = present.any(0)
        for f in np.unique(first[seen]):
            cols = np.flatnonzero(seen & (first == f))
            mask[f, cols] |= _outside_walls(positions[f, cols], scene, float(times[f]))
    if len(positions) < 2 or not scene.walls:
        return mask
    walls = WallSet(scene) if walls is None else walls
    moves = torch.from_numpy(positions)
    for f in range(1, len(positions)):
        rows = np.flatnonzero(present[f - 1] & present[f])
        if rows.size == 0:
            continue
        idx = torch.from_numpy(rows)
        crossed = walls.crossings(
            moves[f - 1, idx], moves[f, idx], float(times[f - 1]), float(times[f])
        )
        mask[f, rows[crossed.numpy()]] = True
    return mask


def leaked_particles(
    positions: np.ndarray,
    scene: Scene,
    times: np.ndarray,
    *,
    walls: WallSet | None = None,
) -> int:
    """Number of particles that leaked in any frame (see :func:`leaked_mask`).

    Args:
        positions: ``[T, N, 3]`` (m), NaN once a particle has left.
        scene: the Scene.
        times: ``[T]`` recorded times (s).
        walls: the Scene's :class:`~granular_pyg.scenes.WallSet`, to reuse (see
            :func:`leaked_mask`).
    """
    return int(leaked_mask(positions, scene, times, walls=walls).any(0).sum())
