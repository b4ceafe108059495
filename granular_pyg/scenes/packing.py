"""Particles placed in a Scene's insertion region without overlap, as LIGGGHTS's
``insert/pack`` does: random positions, each whole particle inside the region, none touching
another (random sequential addition).

The region is the :class:`~granular_pyg.scenes.ParticleSpec`'s box or vertical cylinder. A
random sequential packing jams near a solid fraction of 0.38, and gets slow well before it:
where the particles would fill more than ``max_fraction`` of the region, the region is made
taller (its top raised, up to ``ceiling``), as LIGGGHTS's successive insertions into the same
region stack the bed up over the fill time. A region may also be cut by a predicate
(``inside``): :func:`granular_pyg.scene_start.scene_start` packs a bed too large for its
region below the simulation box's top into the walls' own interior that way.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import ParticleSpec

__all__ = ["Packing", "pack_particles", "region_base_area"]

#: Default solid fraction of the region the packing aims at (LIGGGHTS's batches: 0.15).
MAX_FRACTION = 0.2
#: Rounds of draws after which a region that has not taken every particle grows by half its
#: height on top (up to the ceiling).
ROUNDS_BEFORE_RAISING = 100


@dataclass
class Packing:
    """Non-overlapping particles in a region.

    Attributes:
        positions: ``[N, 3]`` float64 centres (m).
        radii: ``[N]`` float64 (m).
        region_lo, region_hi: ``[3]`` the bounding box of the region used (m): the spec's, its
            top raised where the particles needed more room.
        shape: ``"box"`` or ``"cylinder"`` (the spec's).
        fraction: the particles' volume over the used region's (its box or cylinder, before
            any ``inside`` cut).
        rounds: rounds of random draws it took.
    """

    positions: np.ndarray
    radii: np.ndarray
    region_lo: np.ndarray
    region_hi: np.ndarray
    shape: str
    fraction: float
    rounds: int


def pack_particles(
    spec: ParticleSpec,
    seed: int = 0,
    max_fraction: float = MAX_FRACTION,
    ceiling: float | None = None,
    max_rounds: int = 400,
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Packing:
    """Place ``spec.count`` particles in ``spec``'s region, none overlapping another, each
    entirely inside the region (centre at least its radius from the region's boundary).

    Radii: ``spec.radius``, or drawn from its discrete distribution with its number fractions.
    Each round draws one position for every particle still to place and keeps those that touch
    neither a placed particle nor an earlier one of the same round; the same ``seed`` gives the
    same packing.

    Args:
        spec: the particles and their region.
        seed: random seed.
        max_fraction: the solid fraction of the region above which its top is raised.
        ceiling: the highest the region's top may go (m); None: no limit. Below the ceiling
            the top also rises by half the region's height every 100 rounds that leave
            particles unplaced (a thin region jams well below ``max_fraction``).
        max_rounds: rounds of draws before giving up.
        inside: where within the region a particle may go besides: ``inside(centres [M, 3],
            radii [M]) -> [M] bool`` (True: the whole particle is in the room); a drawn
            particle outside is drawn again. None: the whole region.

    Returns:
        The :class:`Packing`.

    Raises:
        InputError: the region is too small for one particle, or the particles do not all fit
            within ``max_rounds`` (naming how many did and the fix).
    """
    if not 0 < max_fraction < 0.38:
        raise InputError(
            f"max_fraction: expected a solid fraction in (0, 0.38), got {max_fraction}"
        )
    rng = np.random.default_rng(seed)
    sizes, weights = spec.size_distribution
    sizes = np.asarray(sizes, dtype=np.float64)
    if len(sizes) == 1:
        radii = np.full(spec.count, sizes[0])
    else:
        w = np.asarray(weights, dtype=np.float64)
        radii = rng.choice(sizes, size=spec.count, p=w / w.sum())
    radii = np.sort(radii)[::-1].copy()  # the largest first: they find room most easily
    lo, hi = np.asarray(spec.fill_lo, np.float64), np.asarray(spec.fill_hi, np.float64).copy()
    shape = spec.fill_shape
    base = region_base_area(spec)
    solid = float((4.0 / 3.0 * math.pi * radii**3).sum())
    needed = lo[2] + solid / max_fraction / base
    if needed > hi[2]:
        hi[2] = needed if ceiling is None else max(hi[2], min(needed, float(ceiling)))
    r_max = float(radii.max())
    if np.any(hi - lo <= 2 * r_max):
        raise InputError(
            f"particles.fill_lo/fill_hi: the insertion region {lo.tolist()}..{hi.tolist()} m "
            f"is narrower than one particle ({2 * r_max:g} m); enlarge it"
        )
    pos = np.empty((0, 3))
    placed_r = np.empty(0)
    todo = np.arange(spec.count)
    rounds = 0
    while len(todo) and rounds < max_rounds:
        rounds += 1
        if rounds % ROUNDS_BEFORE_RAISING == 0 and (ceiling is None or hi[2] < ceiling):
            # Jammed (a thin region jams early): more room on top for the rest.
            grown = hi[2] + 0.5 * (hi[2] - lo[2])
            hi[2] = grown if ceiling is None else min(grown, float(ceiling))
        cand = _draw(rng, radii[todo], lo, hi, shape)
        ok = np.ones(len(todo), bool)
        if inside is not None:
            ok &= np.asarray(inside(cand, radii[todo]), bool)
        if len(pos):
            i, j, d = _pairs(cand, pos, 2 * r_max)
            ok[i[d < radii[todo][i] + placed_r[j]]] = False
        i, j, d = _self_pairs(cand, 2 * r_max)
        clash = d < radii[todo][i] + radii[todo][j]
        for a, b in sorted(zip(i[clash].tolist(), j[clash].tolist(), strict=True), key=_by_second):
            if ok[a] and ok[b]:
                ok[b] = False  # the earlier one keeps its place
        pos = np.concatenate([pos, cand[ok]])
        placed_r = np.concatenate([placed_r, radii[todo][ok]])
        todo = todo[~ok]
    if len(todo):
        raise InputError(
            f"particles: only {len(pos)} of {spec.count} particles fit in the insertion region "
            f"({shape} {lo.tolist()}..{hi.tolist()} m) without overlap after {rounds} rounds; "
            "make the region taller or wider, or insert fewer particles"
        )
    volume = base * (hi[2] - lo[2])
    return Packing(pos, placed_r, lo, hi, shape, solid / volume, rounds)


def _by_second(pair: tuple[int, int]) -> tuple[int, int]:
    return pair[1], pair[0]


def region_base_area(spec: ParticleSpec) -> float:
    """Horizontal area (m^2) of ``spec``'s insertion region (its box, or the cylinder's disc)."""
    if spec.fill_shape == "cylinder":
        return math.pi * spec.cylinder[2] ** 2
    lo, hi = np.asarray(spec.fill_lo), np.asarray(spec.fill_hi)
    return float((hi[0] - lo[0]) * (hi[1] - lo[1]))


def _draw(rng, radii: np.ndarray, lo: np.ndarray, hi: np.ndarray, shape: str) -> np.ndarray:
    """``[M, 3]`` centres drawn uniformly where a particle of each radius lies entirely inside
    the region (a box ``lo..hi``, or the vertical cylinder inscribed in it)."""
    r = radii[:, None]
    if shape == "box":
        return lo + r + rng.random((len(radii), 3)) * (hi - lo - 2 * r)
    centre = 0.5 * (lo[:2] + hi[:2])
    reach = 0.5 * (hi[0] - lo[0]) - radii
    angle = rng.random(len(radii)) * 2 * math.pi
    rho = reach * np.sqrt(rng.random(len(radii)))  # uniform over the disc
    z = lo[2] + radii + rng.random(len(radii)) * (hi[2] - lo[2] - 2 * radii)
    return np.column_stack([centre[0] + rho * np.cos(angle), centre[1] + rho * np.sin(angle), z])


def _pairs(a: np.ndarray, b: np.ndarray, reach: float):
    """``(i, j, d)``: index arrays of the points ``a[i]``, ``b[j]`` closer than ``reach``."""
    near = cKDTree(b).query_ball_point(a, reach)
    i = np.repeat(np.arange(len(a)), [len(n) for n in near])
    j = np.fromiter((k for n in near for k in n), dtype=np.int64, count=len(i))
    return i, j, np.linalg.norm(a[i] - b[j], axis=1)


def _self_pairs(a: np.ndarray, reach: float):
    """``(i, j, d)`` with ``i < j`` for the points of ``a`` closer than ``reach``."""
    pairs = cKDTree(a).query_pairs(reach, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    return i, j, np.linalg.norm(a[i] - a[j], axis=1)
