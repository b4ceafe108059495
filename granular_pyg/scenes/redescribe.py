"""The same scene described differently: turned about gravity, mirrored, shifted, re-meshed.

None of these changes the physics (gravity fixes only the vertical; the surface, not its
triangles, is what a particle touches), so a model, a feature or a metric must give the same
answer on the result, turned back. They are the variants of ``bench suite=invariance`` and of
the property tests.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import Scene, Wall, WallMotion

__all__ = ["subdivided_scene", "turned_scene"]


def _as_frame(frame) -> np.ndarray:
    q = np.asarray(frame.numpy() if isinstance(frame, torch.Tensor) else frame, np.float64)
    if q.shape != (3, 3) or not np.allclose(q @ q.T, np.eye(3), atol=1e-9):
        raise InputError(f"frame: expected a [3, 3] orthogonal matrix, got {q.tolist()}")
    if not np.allclose(q[2], [0, 0, 1], atol=1e-9) or not np.allclose(
        q[:, 2], [0, 0, 1], atol=1e-9
    ):
        raise InputError(
            "frame: must fix the z axis (gravity): a turn about z or a vertical mirror"
        )
    return q


def _box(lo, hi, q: np.ndarray, shift: np.ndarray) -> tuple[tuple, tuple]:
    """The axis-aligned box holding the box ``lo..hi`` turned by ``q`` and shifted."""
    corners = np.array(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij")).reshape(3, -1).T
    moved = corners @ q.T + shift
    return tuple(moved.min(0).tolist()), tuple(moved.max(0).tolist())


def _turned_motion(m: WallMotion, q: np.ndarray, shift: np.ndarray) -> WallMotion:
    # A rotation axis is a pseudovector: under a mirror (det -1) it turns and flips.
    det = float(np.linalg.det(q))
    return dataclasses.replace(
        m,
        axis=tuple((det * q @ np.asarray(m.axis)).tolist()),
        origin=tuple((q @ np.asarray(m.origin) + shift).tolist()),
        velocity=tuple((q @ np.asarray(m.velocity)).tolist()),
        amplitude=tuple((q @ np.asarray(m.amplitude)).tolist()),
    )


def turned_scene(scene: Scene, frame, shift=(0.0, 0.0, 0.0)) -> Scene:
    """``scene`` turned by ``frame`` (``[3, 3]`` orthogonal, fixing z: see
    :func:`~granular_pyg.geometry.horizontal_frame`), then shifted by ``shift`` (m).

    Walls keep their sides: a mirror also reverses each triangle's vertex order, so a normal
    that pointed into the bed still does (a V2 model sees the same wall). Insertion and domain
    boxes become the axis-aligned boxes around the turned boxes (a cylinder region keeps its
    radius); the outflow height moves with ``shift``.
    """
    q = _as_frame(frame)
    shift = np.asarray(shift, np.float64).reshape(3)
    mirror = np.linalg.det(q) < 0
    walls = [
        Wall(
            w.name,
            w.vertices @ q.T + shift,
            w.faces[:, ::-1].copy() if mirror else w.faces.copy(),
            _turned_motion(w.motion, q, shift),
            w.removal_time,
        )
        for w in scene.walls
    ]
    p = scene.particles
    if p.fill_shape == "cylinder":
        lo, hi = np.asarray(p.fill_lo), np.asarray(p.fill_hi)
        centre, half = q @ ((lo + hi) / 2) + shift, (hi - lo) / 2
        fill = (tuple((centre - half).tolist()), tuple((centre + half).tolist()))
    else:
        fill = _box(p.fill_lo, p.fill_hi, q, shift)
    particles = dataclasses.replace(p, fill_lo=fill[0], fill_hi=fill[1])
    domain = _box(scene.domain_lo, scene.domain_hi, q, shift)
    outflow = None if scene.outflow_z is None else scene.outflow_z + float(shift[2])
    params = dict(scene.params)
    if "outlet_z" in params:
        params["outlet_z"] = float(params["outlet_z"]) + float(shift[2])
    return dataclasses.replace(
        scene,
        walls=walls,
        particles=particles,
        domain_lo=domain[0],
        domain_hi=domain[1],
        outflow_z=outflow,
        params=params,
    )


def _split_in_four(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle into four by its edge midpoints (the same surface; windings kept)."""
    a, b, c = faces.T
    num = len(vertices)
    ab = np.arange(len(faces)) + num
    bc, ca = ab + len(faces), ab + 2 * len(faces)
    mids = np.concatenate(
        [
            (vertices[a] + vertices[b]) / 2,
            (vertices[b] + vertices[c]) / 2,
            (vertices[c] + vertices[a]) / 2,
        ]
    )
    new = np.concatenate(
        [
            np.stack([a, ab, ca], 1),
            np.stack([ab, b, bc], 1),
            np.stack([ca, bc, c], 1),
            np.stack([ab, bc, ca], 1),
        ]
    )
    return np.concatenate([vertices, mids]), new


def subdivided_scene(scene: Scene, times: int = 1) -> Scene:
    """``scene`` with every wall triangle split in four ``times`` times (x4, x16, ...): the
    same surfaces cut into more triangles."""
    if times < 0:
        raise InputError(f"times: expected a count >= 0, got {times}")
    walls = []
    for w in scene.walls:
        vertices, faces = w.vertices, w.faces
        for _ in range(times):
            vertices, faces = _split_in_four(vertices, faces)
        walls.append(Wall(w.name, vertices, faces, w.motion, w.removal_time))
    return dataclasses.replace(scene, walls=walls)
