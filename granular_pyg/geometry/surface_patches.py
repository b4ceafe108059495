"""Surface patches: a wall's triangles grouped into smooth pieces of surface.

A mesher decides how a surface is cut into triangles; the physics sees only the surface. A
particle near a flat or gently curved piece of wall touches it at one point, the closest point
of the piece, however many triangles the piece was cut into. Grouping the triangles into
patches (connected through shared edges, neighbours' normals within :data:`PATCH_ANGLE_DEG`
of each other, either orientation) lets the wall nodes be one per (particle, patch) at the
patch's closest point instead of one per (particle, triangle): splitting a triangle into
coplanar pieces then changes nothing a particle sees (the same surface, the same closest
point, the same normal).
"""

from __future__ import annotations

import math

import numpy as np

from granular_pyg.errors import InputError

__all__ = ["PATCH_ANGLE_DEG", "surface_patches"]

#: Largest angle (degrees) between the normals of two triangles sharing an edge for them to be
#: one patch. 15 degrees joins the facets of a drum shell of 24 or more sections and of a
#: polygonal cone of 24 or more sides, and keeps apart the faces of a hopper wall and its bin
#: (at least 15 degrees apart in every shipped family: the inclined walls stand at most
#: 75 degrees to the horizontal).
PATCH_ANGLE_DEG = 14.9


def _unit_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)


def _find(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def surface_patches(
    vertices: np.ndarray, faces: np.ndarray, max_angle_deg: float = PATCH_ANGLE_DEG
) -> np.ndarray:
    """The patch of each triangle.

    Vertices closer than 1e-9 of the mesh's extent are one vertex (STL files repeat them). Two
    triangles sharing an edge join when their unit normals make an angle of at most
    ``max_angle_deg`` up to orientation (``|n_1 . n_2| >= cos``), so the winding does not
    matter; zero-area triangles stay alone.

    Args:
        vertices: ``[V, 3]`` (m).
        faces: ``[F, 3]`` vertex indices.
        max_angle_deg: the joining angle (degrees), in ``[0, 90)``.

    Returns:
        ``[F]`` int64 patch ids ``0..P-1``, numbered by first triangle.
    """
    if not 0 <= max_angle_deg < 90:
        raise InputError(
            f"max_angle_deg: expected an angle in [0, 90) degrees, got {max_angle_deg}"
        )
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    num = len(faces)
    if num == 0:
        return np.zeros(0, np.int64)
    extent = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
    key = np.round(vertices / max(extent * 1e-9, 1e-300)).astype(np.int64)
    _, welded = np.unique(key, axis=0, return_inverse=True)
    tri = welded.reshape(-1)[faces]
    normals = _unit_normals(vertices, faces)
    edges = np.sort(np.stack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]], 1), axis=2)
    edges = edges.reshape(-1, 2)
    owner = np.repeat(np.arange(num), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    a, b = owner[:-1][same], owner[1:][same]
    cos = math.cos(math.radians(max_angle_deg))
    smooth = np.abs(np.einsum("ij,ij->i", normals[a], normals[b])) >= cos
    parent = np.arange(num)
    for i, j in zip(a[smooth].tolist(), b[smooth].tolist(), strict=True):
        ri, rj = _find(parent, i), _find(parent, j)
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    roots = np.array([_find(parent, i) for i in range(num)])
    _, ids = np.unique(roots, return_inverse=True)
    return ids.astype(np.int64)
