r"""The hopper of the paper: a V-shaped bin with a slot outlet closed by a removable lid.

Geometry (m), gravity along -z::

      z
      ^   x = -W/2 ........ x = +W/2      <- z = height (open top)
      |      \               /
      |       \  particles  /             inclined planes at alpha to the x-y plane bound x
      |        \           /              vertical planes y = +-depth/2 bound y
      |         \_________/               <- z = 0: outlet slot |x| <= opening/2, closed by
      |                                      the lid until t_open
      |   ......................          <- z = outflow_z: particles below leave the scene
      +------------------------------> x

``W = opening + 2 height / tan(alpha)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import trimesh

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import Materials, ParticleSpec, Scene, Wall

__all__ = ["make_hopper"]

#: Random loose packing assumed when estimating the settled bed.
PACKING = 0.6


def _quad_strip(corners: np.ndarray, n_u: int, n_v: int) -> trimesh.Trimesh:
    """A planar quad (corners in order) split into an ``n_u x n_v`` grid of triangle pairs."""
    u = np.linspace(0.0, 1.0, n_u + 1)[:, None, None]
    v = np.linspace(0.0, 1.0, n_v + 1)[None, :, None]
    c = corners
    grid = (1 - v) * ((1 - u) * c[0] + u * c[1]) + v * ((1 - u) * c[3] + u * c[2])
    ij = np.arange((n_u + 1) * (n_v + 1)).reshape(n_u + 1, n_v + 1)
    a, b, cc, d = ij[:-1, :-1].ravel(), ij[1:, :-1].ravel(), ij[1:, 1:].ravel(), ij[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, cc], 1), np.stack([a, cc, d], 1)])
    return trimesh.Trimesh(grid.reshape(-1, 3), faces, process=False)


def _cells(length: float, target: float) -> int:
    return max(1, math.ceil(length / target - 1e-9))


def make_hopper(
    alpha_deg: float = 60.0,
    opening: float = 0.02,
    depth: float = 0.03,
    height: float = 0.1,
    bin_height: float = 0.0,
    num_particles: int = 2000,
    particle_radius: float = 0.0015,
    fill_bottom: float | None = None,
    fill_top: float | None = None,
    t_open: float = 0.05,
    duration: float = 1.0,
    frame_dt: float = 2.5e-3,
    dem_dt: float = 2.0e-5,
    settle_time: float = 0.6,
    outflow_depth: float = 0.03,
    element_size: float = 0.02,
    materials: dict | Materials | None = None,
) -> Scene:
    """Build the hopper Scene.

    Args:
        alpha_deg: angle of the inclined walls to the x-y plane (deg), in (30, 90).
        opening: outlet slot width in x at z = 0 (m); the slot spans the full depth in y.
        depth: distance between the vertical walls (m).
        height: height of the inclined walls' top edge above the outlet (m).
        bin_height: height (m) of a vertical bin on top of the V (its walls continue the
            V's top edges straight up); 0: none.
        num_particles: particles inserted into the fill region.
        particle_radius: (m).
        fill_bottom: lower edge of the fill region (m above the outlet); particles are rained
            into the box between ``fill_bottom`` and ``fill_top`` that fits inside the V. By
            default two radii above the estimated settled bed (packing 0.6), so that later
            batches never land inside the bed.
        fill_top: upper edge of the fill region (m); defaults to ``height + bin_height -
            2 radius``.
        t_open: recorded time (s) at which the lid is removed.
        duration, frame_dt, dem_dt, settle_time: see :class:`Scene` (s).
        outflow_depth: the outflow plane lies this far below the outlet (m).
        element_size: target triangle edge (m) when splitting the walls.
        materials: contact parameters (:class:`Materials` or its fields as a dict).

    Returns:
        A Scene with walls ``hopper`` (static) and ``lid`` (removed at ``t_open``).
    """
    if not (math.isfinite(particle_radius) and particle_radius > 0):
        raise InputError(f"particle_radius: expected a positive radius (m), got {particle_radius}")
    if not 30.0 < alpha_deg < 90.0:
        raise InputError(f"alpha_deg: expected a value in (30, 90), got {alpha_deg}")
    if opening <= 2 * particle_radius:
        raise InputError(f"opening ({opening} m) must exceed one particle diameter")
    if not (math.isfinite(bin_height) and bin_height >= 0):
        raise InputError(f"bin_height: expected a height >= 0 (m), got {bin_height}")
    if not 0 < t_open < duration:
        raise InputError(f"t_open ({t_open} s) must lie inside the recorded time (0, {duration})")
    tan_a = math.tan(math.radians(alpha_deg))
    half_top = opening / 2 + height / tan_a
    o, d, w, h = opening / 2, depth / 2, half_top, height
    slant = math.hypot(h, w - o)
    n_y, n_s = _cells(depth, element_size), _cells(slant, element_size)
    n_h = _cells(h, element_size)
    parts = [
        _quad_strip(np.array([(-o, -d, 0), (-o, d, 0), (-w, d, h), (-w, -d, h)], float), n_y, n_s),
        _quad_strip(np.array([(o, d, 0), (o, -d, 0), (w, -d, h), (w, d, h)], float), n_y, n_s),
    ]
    for y in (-d, d):
        # Front/back walls: the trapezoid between the inclined walls, split in width.
        n_w = _cells(2 * w, element_size)
        parts.append(
            _quad_strip(np.array([(-o, y, 0), (o, y, 0), (w, y, h), (-w, y, h)], float), n_w, n_h)
        )
    if bin_height > 0:
        # The bin: vertical walls on the V's top edges (x = +-w) and on to the front/back walls.
        top, n_b = h + bin_height, _cells(bin_height, element_size)
        for x in (-w, w):
            ys = (-d, d) if x < 0 else (d, -d)  # normals point inwards, as the V's walls
            corners = [(x, ys[0], h), (x, ys[1], h), (x, ys[1], top), (x, ys[0], top)]
            parts.append(_quad_strip(np.array(corners, float), n_y, n_b))
        for y in (-d, d):
            corners = [(-w, y, h), (w, y, h), (w, y, top), (-w, y, top)]
            parts.append(_quad_strip(np.array(corners, float), _cells(2 * w, element_size), n_b))
    hopper = trimesh.util.concatenate(parts)
    hopper.merge_vertices()
    lid = _quad_strip(
        np.array([(-o, -d, 0), (o, -d, 0), (o, d, 0), (-o, d, 0)], float),
        _cells(opening, element_size),
        n_y,
    )

    r = particle_radius
    fill_top = h + bin_height - 2 * r if fill_top is None else fill_top
    if fill_bottom is None:
        # Bed height z of the settled particles: depth * (opening z + z^2 / tan(alpha)) = V.
        bed = num_particles * (4.0 / 3.0) * math.pi * r**3 / PACKING / depth
        fill_bottom = (-opening + math.sqrt(opening**2 + 4 * bed / tan_a)) / (2 / tan_a) + 2 * r
    if not 0 <= fill_bottom < fill_top - 4 * r <= h + bin_height:
        raise InputError(
            f"fill region [{fill_bottom:.4g}, {fill_top:.4g}] m must lie within "
            f"[0, {h + bin_height}] and be "
            "at least two particle diameters tall: raise `height` or lower `num_particles`"
        )
    # Widest box that stays inside the V at its lowest point, one radius (plus margin) from walls.
    half_fill = o + fill_bottom / tan_a - 1.2 * r / math.sin(math.radians(alpha_deg))
    if half_fill <= r:
        raise InputError(
            f"fill region at z = {fill_bottom} m is narrower than a particle: raise fill_bottom"
        )
    particles = ParticleSpec(
        count=int(num_particles),
        radius=float(r),
        fill_lo=(-half_fill, -d + 1.2 * r, fill_bottom),
        fill_hi=(half_fill, d - 1.2 * r, fill_top),
    )
    margin = 4 * r
    if isinstance(materials, Mapping):
        materials = Materials(**materials)
    params = {
        "alpha_deg": alpha_deg,
        "opening": opening,
        "depth": depth,
        "height": height,
        "bin_height": bin_height,
        "num_particles": num_particles,
        "particle_radius": particle_radius,
        "t_open": t_open,
    }
    return Scene(
        name="hopper",
        kind="hopper",
        walls=[
            Wall("hopper", hopper.vertices, hopper.faces),
            Wall("lid", lid.vertices, lid.faces, removal_time=t_open),
        ],
        particles=particles,
        materials=materials or Materials(),
        domain_lo=(-w - margin, -d - margin, -outflow_depth),
        domain_hi=(w + margin, d + margin, h + bin_height + margin),
        outflow_z=-outflow_depth,
        dem_dt=dem_dt,
        settle_time=settle_time,
        duration=duration,
        frame_dt=frame_dt,
        params=params,
    )
