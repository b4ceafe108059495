"""Normalisation statistics of velocities and accelerations, from the training split."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from granular_pyg.geometry import horizontally_isotropic
from granular_pyg.io import Trajectory

__all__ = ["NormalizationStats", "compute_statistics", "horizontally_isotropic"]


@dataclass(frozen=True)
class NormalizationStats:
    """Per-component mean and std (``[3]`` each) of velocities (m/s) and accelerations (m/s^2)."""

    vel_mean: np.ndarray
    vel_std: np.ndarray
    acc_mean: np.ndarray
    acc_std: np.ndarray


def compute_statistics(
    trajectories: list[Trajectory], step: int, noise_std: float = 0.0, isotropic: bool = True
) -> NormalizationStats:
    """Statistics of the finite-difference velocities and accelerations at time-step multiple
    ``step``, over every particle and frame where they are defined (NaN-aware).

    As GNS does, the stds are inflated by the training noise: the random walk of std
    ``noise_std`` (m per step) adds ``noise_std / dt`` to velocities and ``noise_std / dt^2`` to
    accelerations, ``std = sqrt(std^2 + noise^2)``, with ``dt = step * frame_dt``.

    With ``isotropic`` (the default) the horizontal components are made
    :func:`horizontally_isotropic`: gravity fixes only the vertical, and training turns and
    mirrors its windows about it, so x and y share one scale and have mean 0.
    """
    vels, accs = [], []
    for traj in trajectories:
        dt = step * traj.frame_dt
        pos = traj.positions.astype(np.float64)
        vel = (pos[step:] - pos[:-step]) / dt
        acc = (vel[step:] - vel[:-step]) / dt
        vels.append(vel.reshape(-1, 3))
        accs.append(acc.reshape(-1, 3))
    vel_all, acc_all = np.concatenate(vels), np.concatenate(accs)
    dt = step * trajectories[0].frame_dt
    vel_noise, acc_noise = noise_std / dt, noise_std / dt**2
    vel_std = np.sqrt(np.nanstd(vel_all, axis=0) ** 2 + vel_noise**2)
    acc_std = np.sqrt(np.nanstd(acc_all, axis=0) ** 2 + acc_noise**2)
    tiny = math.ulp(1.0)
    vel_mean, acc_mean = np.nanmean(vel_all, axis=0), np.nanmean(acc_all, axis=0)
    if isotropic:
        vel_mean, vel_std = horizontally_isotropic(vel_mean, vel_std)
        acc_mean, acc_std = horizontally_isotropic(acc_mean, acc_std)
    return NormalizationStats(
        vel_mean=vel_mean,
        vel_std=np.maximum(vel_std, tiny),
        acc_mean=acc_mean,
        acc_std=np.maximum(acc_std, tiny),
    )
