"""Sanity checks on an imported LIGGGHTS run, each refusing with the value it found.

* :func:`check_frames_finite`: NaN or Inf in an atom line (position, velocity or radius);
* :func:`check_wall_coordinates`: a wall vertex beyond :data:`MAX_COORDINATE` (1 km);
* :func:`check_wall_units`: a wall far larger than the particles' cloud (an STL in
  millimetres read as metres);
* :func:`check_dem_dt`: a DEM time step that does not fit the particles' motion (the dumps'
  velocities against their position differences over the frame spacing).
"""

from __future__ import annotations

import numpy as np

from granular_pyg.dem.dump import REQUIRED_COLUMNS, DumpFrame
from granular_pyg.errors import InputError

__all__ = [
    "DT_RATIO_LIMIT",
    "MAX_COORDINATE",
    "UNITS_RATIO_LIMIT",
    "check_dem_dt",
    "check_frames_finite",
    "check_wall_coordinates",
    "check_wall_units",
]

#: Largest distance (m) of a wall vertex from the origin.
MAX_COORDINATE = 1e3
#: A wall whose bounding-box diagonal exceeds this many times the particles' is refused.
UNITS_RATIO_LIMIT = 100.0
#: The DEM time step implied by the particles' motion may differ from the given one by at most
#: this factor either way.
DT_RATIO_LIMIT = 2.0
#: Frame pairs sampled by :func:`check_dem_dt`.
DT_SAMPLE_PAIRS = 64


def check_frames_finite(frames: list[DumpFrame]) -> None:
    """Refuse an atom line with NaN or Inf in ``x y z vx vy vz radius``.

    Raises:
        InputError: naming the file, TIMESTEP, atom id and the values.
    """
    for frame in frames:
        cols = [c for c in REQUIRED_COLUMNS if c in frame.columns and c != "id"]
        values = frame.data[:, [frame.columns.index(c) for c in cols]]
        bad = ~np.isfinite(values)
        if not bad.any():
            continue
        row = int(np.flatnonzero(bad.any(1))[0])
        atom = frame.data[row, frame.columns.index("id")]
        shown = ", ".join(f"{c} = {float(v):.6g}" for c, v in zip(cols, values[row], strict=True))
        names = [c for c, b in zip(cols, bad[row], strict=True) if b]
        what = (
            "velocity"
            if all(c.startswith("v") for c in names)
            else "radius"
            if names == ["radius"]
            else "position"
        )
        raise InputError(
            f"{frame.where}: atom id {int(atom)} has a non-finite {what} ({shown}); "
            f"{int(bad.any(1).sum())} atom line(s) of this frame do: the run blew up (too large "
            "a time step, overlapping particles) or the file is corrupt; fix the run or drop "
            "these frames"
        )


def check_wall_coordinates(name: str, vertices: np.ndarray, source: str) -> None:
    """Refuse a wall vertex farther than :data:`MAX_COORDINATE` from the origin.

    Args:
        name: the wall's name.
        vertices: ``[V, 3]`` (m).
        source: the STL file, for the message.
    """
    dist = np.linalg.norm(vertices, axis=1)
    if len(dist) and not dist.max() <= MAX_COORDINATE:
        k = int(np.nanargmax(np.where(np.isfinite(dist), dist, np.inf)))
        raise InputError(
            f"wall {name} ({source}): vertex {k} at {vertices[k].tolist()} lies {dist[k]:.4g} m "
            f"from the origin, beyond {MAX_COORDINATE:g} m; the STL is probably not in metres: "
            "pass --units mm (or units: for it in walls.yaml), or fix the file"
        )


def check_wall_units(
    walls: list[tuple[str, np.ndarray, str, str]], positions: np.ndarray, radius: float
) -> None:
    """Refuse a wall whose extent is more than :data:`UNITS_RATIO_LIMIT` times the particles'.

    Args:
        walls: ``(name, vertices [V, 3] (m), source, units)`` per wall.
        positions: ``[T, N, 3]`` particle centres (m), NaN where absent.
        radius: the largest particle radius (m).

    Raises:
        InputError: naming the wall, both extents and the likely fix (``--units mm``).
    """
    finite = positions[np.isfinite(positions).all(-1)]
    if not len(finite):
        return
    cloud = float(np.linalg.norm(finite.max(0) - finite.min(0)))
    scale = max(cloud, 20.0 * float(radius))
    for name, vertices, source, units in walls:
        extent = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
        if extent > UNITS_RATIO_LIMIT * scale:
            hint = (
                "it is likely in millimetres: pass --units mm (or units: mm for it in walls.yaml)"
                if units == "m"
                else f"check its units (read as {units})"
            )
            raise InputError(
                f"wall {name} ({source}): spans {extent:.4g} m, more than "
                f"{UNITS_RATIO_LIMIT:g} x the particles' {cloud:.4g} m (radius {radius:.4g} m); "
                f"{hint}"
            )


def check_dem_dt(
    positions: np.ndarray,
    velocities: np.ndarray,
    timesteps: np.ndarray,
    dem_dt: float,
    source: str,
) -> float | None:
    """Refuse a DEM time step that does not fit the particles' motion.

    Between two frames ``k`` steps apart a particle moves by about ``(v0 + v1) / 2 * k * dt``
    (exact under a constant force). For each particle and sampled frame pair that moves more
    than round-off, ``ratio = d . v_mean / (|v_mean|^2 k dt)``; the median ratio times
    ``dem_dt`` is the time step the dumps imply.

    Args:
        positions: ``[T, N, 3]`` (m), NaN where absent.
        velocities: ``[T, N, 3]`` (m/s).
        timesteps: ``[T]`` the frames' TIMESTEPs.
        dem_dt: the time step to check (s).
        source: where ``dem_dt`` came from (``--dem-dt``, ``timestep in in.run:12``).

    Returns:
        The implied time step (s), or None when nothing moves enough to tell.

    Raises:
        InputError: the implied time step differs by more than :data:`DT_RATIO_LIMIT` x,
            naming both values.
    """
    if len(timesteps) < 2:
        return None
    pairs = np.unique(np.linspace(0, len(timesteps) - 2, DT_SAMPLE_PAIRS).round().astype(int))
    ratios = []
    for k in pairs:
        x0, x1 = positions[k].astype(np.float64), positions[k + 1].astype(np.float64)
        v = 0.5 * (velocities[k].astype(np.float64) + velocities[k + 1].astype(np.float64))
        d = x1 - x0
        ok = np.isfinite(d).all(1) & np.isfinite(v).all(1)
        if not ok.any():
            continue
        d, v = d[ok], v[ok]
        noise = 1e-5 * np.abs(x0[ok]).max() + 1e-12
        speed2 = np.einsum("ij,ij->i", v, v)
        moving = (np.linalg.norm(d, axis=1) > 100 * noise) & (speed2 > 0)
        span = float(timesteps[k + 1] - timesteps[k]) * dem_dt
        ratios.append(np.einsum("ij,ij->i", d[moving], v[moving]) / (speed2[moving] * span))
    ratios = np.concatenate(ratios) if ratios else np.empty(0)
    if not len(ratios):
        return None
    ratio = float(np.median(ratios))
    implied = ratio * dem_dt
    if not (1 / DT_RATIO_LIMIT <= ratio <= DT_RATIO_LIMIT):
        raise InputError(
            f"{source}: a DEM time step of {dem_dt:.6g} s does not fit the particles' motion: "
            f"their velocities and position changes between frames imply {implied:.3g} s "
            f"(median over {len(ratios)} particle moves, {ratio:.3g} x); give the run's "
            "`timestep` (--dem-dt, or read it with --input/--log)"
        )
    return implied
