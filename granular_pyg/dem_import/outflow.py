"""Particles leaving an imported run, exactly as the learned rollout lets them leave.

The rollout's rule (``granular_pyg.simulator``): a particle whose centre is below the Scene's
``outflow_z`` leaves for good, NaN from that frame on. A LIGGGHTS run may keep such particles
(a catch box below the outlet), so :func:`apply_outflow` blanks them from the first frame they
are below, whatever the later dumps say. A particle absent from a dump is gone too; one that is
absent from a frame and back in a later one cannot be represented, and
:func:`check_no_reappearance` refuses it. A particle may first appear late (inserted during the
recording).
"""

from __future__ import annotations

import numpy as np

from granular_pyg.errors import InputError

__all__ = ["apply_outflow", "check_no_reappearance", "count_vanished"]


def apply_outflow(positions: np.ndarray, velocities: np.ndarray, outflow_z: float) -> int:
    """Set positions and velocities to NaN from the first frame a particle's centre is below
    ``outflow_z``, in place.

    Args:
        positions: ``[T, N, 3]`` (m), NaN where absent.
        velocities: ``[T, N, 3]`` (m/s).
        outflow_z: the outflow height (m); strictly below leaves (as in the rollout).

    Returns:
        The number of particles that left.
    """
    below = positions[..., 2] < outflow_z  # NaN compares False
    gone = np.logical_or.accumulate(below, axis=0)
    positions[gone] = np.nan
    velocities[gone] = np.nan
    return int(gone[-1].sum()) if len(gone) else 0


def check_no_reappearance(positions: np.ndarray, ids: np.ndarray, timesteps: np.ndarray) -> None:
    """Refuse a particle that is absent from a frame after it appeared, and back later.

    Args:
        positions: ``[T, N, 3]`` (m), NaN where absent (after :func:`apply_outflow`).
        ids: ``[N]`` LIGGGHTS atom ids.
        timesteps: ``[T]`` the frames' TIMESTEPs.

    Raises:
        InputError: naming the first such particle's id, the frame it is missing from and the
            frame it is back in, and how many particles do this.
    """
    present = np.isfinite(positions[..., 0])
    seen = np.logical_or.accumulate(present, axis=0)
    missing = seen & ~present
    back = present & np.logical_or.accumulate(missing, axis=0)
    if not back.any():
        return
    frames, particles = np.nonzero(back)
    first = int(np.argmin(frames))
    n, t_back = int(particles[first]), int(frames[first])
    t_missing = int(np.flatnonzero(missing[:t_back, n])[0])
    count = len(np.unique(particles))
    raise InputError(
        f"dumps: particle id {int(ids[n])} is missing from TIMESTEP {int(timesteps[t_missing])} "
        f"(frame {t_missing}) but back at TIMESTEP {int(timesteps[t_back])} (frame {t_back}) "
        f"({count} particle(s) do this); a particle that left cannot come back: dump all atoms "
        "in every frame (dump ... all custom ...), or pass the dumps of one run only"
    )


def count_vanished(
    positions: np.ndarray,
    left: int,
    outflow_z: float | None,
    ids: np.ndarray,
    timesteps: np.ndarray,
) -> int:
    """The particles that are gone from the last frame other than below ``outflow_z`` (deleted
    by LIGGGHTS at its box, or by a ``delete_atoms``); one ``warning:`` line on standard error
    when there are any, since a rollout treats them as gone through the floor.

    Args:
        positions: ``[T, N, 3]`` (m), NaN where absent (after :func:`apply_outflow`).
        left: the particles :func:`apply_outflow` removed.
        outflow_z: the outflow height (m), or None.
        ids: ``[N]`` LIGGGHTS atom ids.
        timesteps: ``[T]`` the frames' TIMESTEPs.

    Returns:
        Their number (the imported metadata's ``vanished``).
    """
    import sys

    if not len(positions):
        return 0
    present = np.isfinite(positions[..., 0])
    gone = present.any(0) & ~present[-1]
    vanished = max(int(gone.sum()) - int(left), 0)
    if vanished:
        first = int(ids[np.flatnonzero(gone)[0]])
        fix = (
            "pass --outflow-z <z> (the height below which particles leave) if they leave "
            "through an outlet"
            if outflow_z is None
            else f"they were never below --outflow-z {outflow_z:g}; check it"
        )
        print(
            f"warning: dumps: {vanished} particle(s) vanish from the dumps before TIMESTEP "
            f"{int(timesteps[-1])} (first: atom id {first}) and are counted as vanished in the "
            f"metadata; {fix}",
            file=sys.stderr,
        )
    return vanished
