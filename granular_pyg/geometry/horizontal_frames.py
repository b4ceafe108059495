"""Turns about the gravity axis (z) and mirrors through vertical planes: the symmetries of a
granular scene under gravity, as ``[3, 3]`` orthogonal matrices that fix z."""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["horizontal_frame", "horizontally_isotropic", "random_horizontal_frame"]


def horizontal_frame(angle_deg: float, mirror: bool = False) -> torch.Tensor:
    """The turn by ``angle_deg`` about +z (right-handed), after the mirror ``x -> -x`` if
    ``mirror``: ``[3, 3]`` float64, applied to column vectors (``v' = Q v``).

    Every turn and vertical mirror is one of these (a mirror through any vertical plane is
    ``x -> -x`` followed by a turn).
    """
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    turn = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    if mirror:
        turn = turn @ torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
    return turn


def random_horizontal_frame(generator: torch.Generator) -> torch.Tensor:
    """A turn about z by an angle uniform in [0, 360) degrees, mirrored with probability 1/2,
    drawn from ``generator`` (two draws): ``[3, 3]`` float64."""
    u = torch.rand(2, generator=generator, dtype=torch.float64)
    return horizontal_frame(360.0 * float(u[0]), bool(u[1] < 0.5))


def horizontally_isotropic(mean, std) -> tuple[np.ndarray, np.ndarray]:
    """Per-component statistics ``mean, std [3]`` made invariant under turns about the z axis
    and vertical mirrors: the statistics of the same data seen in every horizontal direction.
    The horizontal means become 0 and both horizontal stds ``sqrt(mean_xy(std^2 + mean^2))``
    (the second moment is kept); z is unchanged.

    Returns:
        ``(mean [3], std [3])`` float64 arrays.
    """
    mean = np.asarray(mean, np.float64).reshape(3).copy()
    std = np.asarray(std, np.float64).reshape(3).copy()
    second = float(np.mean(std[:2] ** 2 + mean[:2] ** 2))
    mean[:2], std[:2] = 0.0, math.sqrt(second)
    return mean, std
