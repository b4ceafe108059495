"""Where points lie relative to a Scene's walls, and the check that an insertion region is inside.

LIGGGHTS inserts particles into a region without looking at the walls, so a region that crosses a
wall or lies outside the equipment inserts particles into or behind it.
:func:`check_insertion_region` refuses such a region before LIGGGHTS starts, looking at the walls
present at recorded time 0 in their pose then (the pose of the whole fill-and-settle phase):

1. the region's bounding box must lie inside the walls' bounding box;
2. no wall vertex may lie inside the region (a wall wholly inside it);
3. no wall may come closer than one (largest) particle radius to the region's surface, tested at
   points of the surface at most one radius apart, so that a wall crossing the surface is always
   caught;
4. the region must be on the inner side of the walls: inside the closed surface they form when
   every edge is shared by exactly two triangles (a ray-parity test), else inside the walls'
   convex hull (an open-topped hopper or silo).

Given 2 and 3, the whole region is on one side of every wall, so 4 tests a few points only.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

from granular_pyg.errors import InputError
from granular_pyg.geometry import closest_point_on_triangles
from granular_pyg.scenes.scene import ParticleSpec, Scene

__all__ = [
    "check_insertion_region",
    "inside_closed_surface",
    "inside_convex_hull",
    "inside_walls",
    "is_closed_surface",
    "region_surface_points",
    "walls_at",
]

#: Ray directions of the parity test (unit vectors chosen to miss axis-aligned edges); a point
#: is inside when at least two of the three rays say so.
_RAYS = np.array([[0.5736, 0.6293, 0.5244], [-0.6113, 0.3179, 0.7247], [0.2819, -0.8388, 0.4658]])
_RAYS /= np.linalg.norm(_RAYS, axis=1, keepdims=True)


def walls_at(scene: Scene, t: float = 0.0) -> tuple[np.ndarray, list[str]]:
    """``(triangles [F, 3, 3] (m, world frame), wall name per triangle [F])`` of the walls
    present at recorded time ``t`` (s), in their pose at ``t``."""
    tris, names = [], []
    for wall in scene.walls:
        if wall.present(t):
            tris.append(wall.vertices_at(t)[wall.faces])
            names += [wall.name] * len(wall.faces)
    if not tris:
        return np.zeros((0, 3, 3)), []
    return np.concatenate(tris), names


def is_closed_surface(triangles: np.ndarray) -> bool:
    """Whether every edge of ``triangles [F, 3, 3]`` is shared by exactly two triangles
    (vertices matched by exact coordinates)."""
    if len(triangles) == 0:
        return False
    _, index = np.unique(triangles.reshape(-1, 3), axis=0, return_inverse=True)
    faces = index.reshape(-1, 3)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def _ray_hits(points: np.ndarray, direction: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``[P]`` number of triangles the ray ``points + s direction`` (s > 0) crosses
    (Moller-Trumbore, every pair)."""
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    pvec = np.cross(direction, e2)  # [F, 3]
    det = (e1 * pvec).sum(1)
    ok = np.abs(det) > 1e-30
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    counts = np.zeros(len(points), np.int64)
    for start in range(0, len(points), 256):
        s = points[start : start + 256, None, :] - v0[None]  # [p, F, 3]
        u = (s * pvec).sum(2) * inv
        q = np.cross(s, e1[None])
        v = (q * direction).sum(2) * inv
        dist = (q * e2[None]).sum(2) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (dist > 0)
        counts[start : start + 256] = hit.sum(1)
    return counts


def inside_closed_surface(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``[P]`` bool: points ``[P, 3]`` (m) inside the closed surface ``triangles [F, 3, 3]`` by
    ray parity (several closed parts count together: a point in a drum but in none of its
    lifter bars is inside). Majority of three rays, so a ray through an edge cannot decide."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    votes = sum((_ray_hits(points, d, triangles) % 2 == 1).astype(int) for d in _RAYS)
    return votes >= 2


def inside_convex_hull(
    points: np.ndarray, vertices: np.ndarray | ConvexHull, tol: float | np.ndarray = 0.0
) -> np.ndarray:
    """``[P]`` bool: points ``[P, 3]`` (m) inside the convex hull of ``vertices [V, 3]`` (m; or
    that hull, built once by the caller) by more than ``tol`` (m, one number or ``[P]``, one
    per point, e.g. each particle's radius; negative lets points stick out by as much)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    hull = vertices
    if not isinstance(hull, ConvexHull):
        try:
            hull = ConvexHull(np.asarray(vertices, np.float64))
        except QhullError:  # flat walls: no volume inside
            return np.zeros(len(points), bool)
    tol = np.broadcast_to(np.asarray(tol, np.float64), (len(points),))
    signed = points @ hull.equations[:, :3].T + hull.equations[:, 3]  # <= 0 inside
    return np.all(signed <= -tol[:, None], axis=1)


def inside_walls(points: np.ndarray, scene: Scene, t: float = 0.0) -> np.ndarray:
    """``[P]`` bool: points ``[P, 3]`` (m) on the inner side of the walls present at recorded
    time ``t`` (s): inside their closed surface when they form one, else inside their convex
    hull (see the module docstring)."""
    triangles, _ = walls_at(scene, t)
    if is_closed_surface(triangles):
        return inside_closed_surface(points, triangles)
    return inside_convex_hull(points, triangles.reshape(-1, 3))


def region_surface_points(particles: ParticleSpec, spacing: float) -> np.ndarray:
    """``[S, 3]`` points (m) on the surface of the insertion region, at most ``spacing`` (m)
    apart along it, its corners and edges included."""
    lo, hi = np.asarray(particles.fill_lo, float), np.asarray(particles.fill_hi, float)
    if particles.fill_shape == "cylinder":
        cx, cy, radius, z_lo, z_hi = particles.cylinder
        n_t = max(8, math.ceil(2 * math.pi * radius / spacing))
        theta = 2 * math.pi * np.arange(n_t) / n_t
        zs = np.linspace(z_lo, z_hi, max(2, math.ceil((z_hi - z_lo) / spacing) + 1))
        side = np.stack(
            [
                np.tile(cx + radius * np.cos(theta), len(zs)),
                np.tile(cy + radius * np.sin(theta), len(zs)),
                np.repeat(zs, n_t),
            ],
            1,
        )
        caps = [side]
        for rho in np.linspace(0.0, radius, max(2, math.ceil(radius / spacing) + 1))[:-1]:
            n = max(1, math.ceil(2 * math.pi * rho / spacing))
            ang = 2 * math.pi * np.arange(n) / n
            ring = np.stack([cx + rho * np.cos(ang), cy + rho * np.sin(ang)], 1)
            for z in (z_lo, z_hi):
                caps.append(np.column_stack([ring, np.full(n, z)]))
        return np.concatenate(caps)
    axes = [
        np.linspace(lo[i], hi[i], max(2, math.ceil((hi[i] - lo[i]) / spacing) + 1))
        for i in range(3)
    ]
    faces = []
    for i in range(3):
        j, k = [a for a in range(3) if a != i]
        gj, gk = np.meshgrid(axes[j], axes[k], indexing="ij")
        for value in (lo[i], hi[i]):
            pts = np.empty((gj.size, 3))
            pts[:, i], pts[:, j], pts[:, k] = value, gj.ravel(), gk.ravel()
            faces.append(pts)
    return np.concatenate(faces)


def _first_near(
    points: np.ndarray, triangles: np.ndarray, distance: float
) -> tuple[int, int] | None:
    """``(point, triangle)`` of the first pair (by triangle) closer than ``distance`` (m), or
    None: bounding boxes first, then the exact distance of the candidate pairs."""
    lo = triangles.min(1) - distance
    hi = triangles.max(1) + distance
    for start in range(0, len(triangles), 64):
        near = np.all(
            (points[None] >= lo[start : start + 64, None])
            & (points[None] <= hi[start : start + 64, None]),
            axis=2,
        )  # [f, P]
        tri, pt = np.nonzero(near)
        if tri.size == 0:
            continue
        tri += start
        _, sq = closest_point_on_triangles(
            torch.from_numpy(points[pt]), torch.from_numpy(triangles[tri]), validate=False
        )
        close = np.flatnonzero(sq.numpy() < distance**2)
        if close.size:
            return int(pt[close[0]]), int(tri[close[0]])
    return None


def _inside_region(points: np.ndarray, particles: ParticleSpec) -> np.ndarray:
    """``[P]`` bool: points strictly inside the insertion region."""
    lo, hi = np.asarray(particles.fill_lo, float), np.asarray(particles.fill_hi, float)
    if particles.fill_shape == "cylinder":
        cx, cy, radius, z_lo, z_hi = particles.cylinder
        rho = np.hypot(points[:, 0] - cx, points[:, 1] - cy)
        return (rho < radius) & (points[:, 2] > z_lo) & (points[:, 2] < z_hi)
    return np.all((points > lo) & (points < hi), axis=1)


def _describe(particles: ParticleSpec) -> str:
    if particles.fill_shape == "cylinder":
        cx, cy, radius, z_lo, z_hi = particles.cylinder
        return (
            f"insertion cylinder (centre ({cx:.4g}, {cy:.4g}) m, radius {radius:.4g} m, "
            f"z {z_lo:.4g}..{z_hi:.4g} m)"
        )
    lo = ", ".join(f"{v:.4g}" for v in particles.fill_lo)
    hi = ", ".join(f"{v:.4g}" for v in particles.fill_hi)
    return f"insertion box ({lo})..({hi}) m"


def check_insertion_region(scene: Scene, fix: str = "move or shrink the region") -> None:
    """Refuse an insertion region that is not inside the walls, away from every wall (see the
    module docstring for the four tests).

    Args:
        scene: the set-up; its walls present at recorded time 0 count, in their pose then.
        fix: how the user changes the region, appended to every message (e.g. the config key).

    Raises:
        InputError: naming the region, the wall concerned and the fix.
    """
    p = scene.particles
    region = _describe(p)
    triangles, names = walls_at(scene, 0.0)
    if len(triangles) == 0:
        raise InputError(f"scene {scene.name}: no wall is present at t = 0 to hold the {region}")
    present = sorted(set(names), key=names.index)
    lo, hi = np.asarray(p.fill_lo, float), np.asarray(p.fill_hi, float)
    if scene.outflow_z is not None and lo[2] <= scene.outflow_z:
        raise InputError(
            f"scene {scene.name}: the {region} reaches below the outflow plane z = "
            f"{scene.outflow_z:.4g} m, where particles leave: {fix}"
        )
    w_lo, w_hi = triangles.reshape(-1, 3).min(0), triangles.reshape(-1, 3).max(0)
    if np.any(lo < w_lo) or np.any(hi > w_hi):
        box = f"({', '.join(f'{v:.4g}' for v in w_lo)})..({', '.join(f'{v:.4g}' for v in w_hi)})"
        raise InputError(
            f"scene {scene.name}: the {region} lies outside the bounding box {box} m of the "
            f"walls {present}: {fix} to lie inside the equipment"
        )
    for wall in scene.walls:
        if not wall.present(0.0):
            continue
        vertices = wall.vertices_at(0.0)
        inside = _inside_region(vertices, p)
        if inside.any():
            first = ", ".join(f"{v:.4g}" for v in vertices[np.flatnonzero(inside)[0]])
            raise InputError(
                f"scene {scene.name}: wall {wall.name} has {int(inside.sum())} vertices inside "
                f"the {region} (first at ({first}) m), so particles would be inserted into it: "
                f"{fix}"
            )
    clearance = float(p.radius)
    samples = region_surface_points(p, clearance)
    found = _first_near(samples, triangles, clearance)
    if found is not None:
        near = ", ".join(f"{v:.4g}" for v in samples[found[0]])
        raise InputError(
            f"scene {scene.name}: the {region} crosses or comes within one particle radius "
            f"({clearance * 1e3:.3g} mm) of wall {names[found[1]]} near ({near}) m: {fix} so "
            "that it keeps at least one particle radius from every wall"
        )
    probe = np.concatenate([[(lo + hi) / 2], samples[:: max(1, len(samples) // 16)]])
    closed = is_closed_surface(triangles)
    if closed:
        inside = inside_closed_surface(probe, triangles)
        how = f"the closed surface of the walls {present}"
    else:
        inside = inside_convex_hull(probe, triangles.reshape(-1, 3))
        how = f"the convex hull of the walls {present} (they do not form a closed surface)"
    if not inside.all():
        raise InputError(
            f"scene {scene.name}: the {region} lies outside {how}: {fix} to lie inside the "
            "equipment"
        )
