"""Rigid motions of wall meshes: rotation matrices and poses about an axis.

A pose ``(rotation [3, 3], translation [3])`` maps mesh-frame coordinates to the world frame:
``x_world = rotation @ x_mesh + translation``.
"""

from __future__ import annotations

import math

import torch

from granular_pyg.errors import InputError

__all__ = ["pose_about_axis", "rotation_about_axis"]


def rotation_about_axis(
    axis: torch.Tensor | tuple[float, float, float], angle: float, dtype=torch.float64
) -> torch.Tensor:
    """Rotation matrix for ``angle`` (rad, right-handed) about ``axis`` (Rodrigues).

    Args:
        axis: ``[3]`` direction, any non-zero length.
        angle: rotation angle in radians.
        dtype: dtype of the result.

    Returns:
        ``[3, 3]`` orthonormal matrix with determinant +1.
    """
    axis = torch.as_tensor(axis, dtype=torch.float64)
    norm = float(torch.linalg.vector_norm(axis))
    if axis.shape != (3,) or not math.isfinite(norm) or norm == 0.0:
        raise InputError(f"axis: expected a finite non-zero 3-vector, got {axis.tolist()}")
    x, y, z = (axis / norm).tolist()
    k = torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=torch.float64)
    rot = torch.eye(3, dtype=torch.float64) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
    return rot.to(dtype)


def pose_about_axis(
    axis: torch.Tensor | tuple[float, float, float],
    angle: float,
    origin: torch.Tensor | tuple[float, float, float] = (0.0, 0.0, 0.0),
    dtype=torch.float64,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pose of a mesh turned by ``angle`` (rad) about the line through ``origin`` along ``axis``.

    Returns:
        ``(rotation [3, 3], translation [3])`` with ``x_world = rotation @ x_mesh + translation``.
    """
    rot = rotation_about_axis(axis, angle, torch.float64)
    origin = torch.as_tensor(origin, dtype=torch.float64)
    return rot.to(dtype), (origin - rot @ origin).to(dtype)
