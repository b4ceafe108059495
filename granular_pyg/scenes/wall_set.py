"""The walls of a Scene as the learned simulator queries them, at any recorded time."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from granular_pyg.geometry import WallIndex, triangle_normals
from granular_pyg.scenes.scene import Scene, Wall

__all__ = ["WallContacts", "WallSet"]


class WallContacts(NamedTuple):
    """Particle-triangle pairs closer than a radius at one time, world frame.

    Attributes:
        point_idx: ``[K]`` int64 index of the particle.
        tri_idx: ``[K]`` int64 triangle index, global over the WallSet's walls.
        closest: ``[K, 3]`` closest point on the triangle (m).
        normal: ``[K, 3]`` the triangle's unit normal from its vertex order (right-hand rule).
        velocity: ``[K, 3]`` the wall's velocity at the closest point (m/s).
    """

    point_idx: torch.Tensor
    tri_idx: torch.Tensor
    closest: torch.Tensor
    normal: torch.Tensor
    velocity: torch.Tensor


class WallSet:
    """One :class:`~granular_pyg.geometry.WallIndex` per wall, built once; poses, removals and
    wall velocities follow the walls' motions at the query time.

    Args:
        walls: a Scene or its list of walls.
    """

    def __init__(self, walls: Scene | list[Wall]) -> None:
        self.walls = list(walls.walls if isinstance(walls, Scene) else walls)
        self.indices = [
            WallIndex(torch.from_numpy(w.vertices), torch.from_numpy(w.faces)) for w in self.walls
        ]
        self.normals = [triangle_normals(index.triangles) for index in self.indices]  # mesh frame
        counts = [len(w.faces) for w in self.walls]
        self.offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
        self.num_triangles = int(sum(counts))

    def __repr__(self) -> str:
        names = ", ".join(f"{w.name}: {len(w.faces)}" for w in self.walls)
        return f"WallSet({names})"

    def contacts(self, points: torch.Tensor, radius: float, time: float) -> WallContacts:
        """Every (particle, triangle) pair closer than ``radius`` among the walls present at
        ``time``, sorted by wall, then particle, then triangle.

        Args:
            points: ``[P, 3]`` world positions (m), float32 or float64.
            radius: cut-off (m).
            time: recorded time (s) that sets each wall's pose and presence.
        """
        dtype = points.dtype
        parts = []
        for wall, index, normals, offset in zip(
            self.walls, self.indices, self.normals, self.offsets, strict=True
        ):
            if not wall.present(time):
                continue
            rot_np, shift_np = wall.motion.pose(time)
            rot = torch.from_numpy(rot_np).to(dtype)
            shift = torch.from_numpy(shift_np).to(dtype)
            found = index.pairs(points, radius, rot, shift)
            normal = normals[found.tri_idx].to(dtype) @ rot.T
            velocity = torch.zeros_like(found.closest)
            m = wall.motion
            if m.kind == "rotation" and time >= m.start_time and m.omega != 0.0:
                axis = torch.tensor(m.axis, dtype=dtype)
                omega = m.omega * axis / torch.linalg.vector_norm(axis)
                arm = found.closest - torch.tensor(m.origin, dtype=dtype)
                velocity = torch.linalg.cross(omega.expand_as(arm), arm)
            parts.append((found.point_idx, found.tri_idx + offset, found.closest, normal, velocity))
        if not parts:
            empty = torch.zeros(0, dtype=torch.int64)
            vec = points.new_zeros((0, 3))
            return WallContacts(empty, empty.clone(), vec, vec.clone(), vec.clone())
        return WallContacts(*(torch.cat(cols) for cols in zip(*parts, strict=True)))
