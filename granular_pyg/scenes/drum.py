"""The rotating drum of the paper: a closed cylinder about the y axis, partly filled.

Initial fill (a documented alternative to the paper's "resting fill rotated about the x axis"):
particles are rained into the largest box inside the cylinder's lower half and settle under
gravity with the drum at rest for ``settle_time``; the drum then rotates from recorded time 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import trimesh

from granular_pyg.errors import InputError
from granular_pyg.scenes.scene import Materials, ParticleSpec, Scene, Wall, WallMotion

__all__ = ["make_drum"]

#: Random loose packing assumed when turning a fill fraction into a particle count.
PACKING = 0.6


def _bed_surface(radius: float, area: float) -> float:
    """Height (m, relative to the axis) of a flat bed of cross-section ``area`` in a circle."""
    lo, hi = -radius, radius
    for _ in range(60):  # bisection on the circular-segment area
        z = 0.5 * (lo + hi)
        depth = z + radius
        segment = radius**2 * math.acos(-z / radius) + z * math.sqrt(
            max(0.0, 2 * radius * depth - depth**2)
        )
        lo, hi = (z, hi) if segment < area else (lo, z)
    return 0.5 * (lo + hi)


def make_drum(
    drum_radius: float = 0.05,
    length: float = 0.03,
    omega: float = 2.0,
    fill_fraction: float = 0.35,
    particle_radius: float = 0.002,
    num_particles: int | None = None,
    sections: int = 48,
    duration: float = 2.0,
    frame_dt: float = 5.0e-3,
    dem_dt: float = 2.0e-5,
    settle_time: float = 0.5,
    materials: dict | Materials | None = None,
    spin_start: float = 0.0,
    spin_stop: float | None = None,
    spin_reverse: float | None = None,
) -> Scene:
    """Build the drum Scene.

    Args:
        drum_radius: inner radius of the cylinder (m).
        length: cylinder length along y (m).
        omega: angular velocity about +y (rad/s, right-handed).
        fill_fraction: bulk volume of the bed over the drum volume; sets the particle count
            with a packing of 0.6 unless ``num_particles`` is given.
        particle_radius: (m).
        num_particles: explicit particle count (overrides ``fill_fraction``).
        sections: facets around the circumference.
        duration, frame_dt, dem_dt, settle_time: see :class:`Scene` (s).
        materials: contact parameters (:class:`Materials` or its fields as a dict).
        spin_start: recorded time (s) at which the drum starts turning; before it the settled
            bed lies at rest in a drum at rest (a resting state the data then holds).
        spin_stop: recorded time (s) at which the drum stops (the bed comes to rest again), or
            None (never); a value at or beyond ``duration`` also means never within the record.
        spin_reverse: recorded time (s) at which the drum turns back the other way at the
            same speed (the bed's slope flips), or None (never); a value at or after the
            stop (or ``duration``) also means never.

    Returns:
        A Scene with one wall ``drum`` rotating about the y axis through the origin.
    """
    if not (math.isfinite(particle_radius) and particle_radius > 0):
        raise InputError(f"particle_radius: expected a positive radius (m), got {particle_radius}")
    if not 0 < fill_fraction < 0.6:
        raise InputError(f"fill_fraction: expected a value in (0, 0.6), got {fill_fraction}")
    if sections < 12:
        raise InputError(f"sections: expected at least 12, got {sections}")
    r = particle_radius
    if num_particles is None:
        bed = fill_fraction * math.pi * drum_radius**2 * length * PACKING
        num_particles = round(bed / (4.0 / 3.0 * math.pi * r**3))
    # A closed cylinder along z, turned so its axis is y.
    mesh = trimesh.creation.cylinder(radius=drum_radius, height=length, sections=sections)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, (1, 0, 0)))
    # Inscribed polygon: the flat facets sit closer to the axis than drum_radius.
    inner = drum_radius * math.cos(math.pi / sections)
    # Rain particles into a box above the settled bed, inside the circle.
    bed = num_particles * (4.0 / 3.0) * math.pi * r**3 / PACKING / length
    z_lo = _bed_surface(inner, bed) + 2 * r
    z_hi = 0.7 * inner
    half = math.sqrt(inner**2 - max(z_lo**2, z_hi**2)) - 1.5 * r
    if z_hi - z_lo < 4 * r or half < 2 * r:
        raise InputError(
            f"the drum is too full to rain {num_particles} particles in above the bed: "
            "lower fill_fraction or num_particles"
        )
    particles = ParticleSpec(
        count=int(num_particles),
        radius=float(r),
        fill_lo=(-half, -length / 2 + 1.5 * r, z_lo),
        fill_hi=(half, length / 2 - 1.5 * r, z_hi),
    )
    margin = 4 * r
    ext = drum_radius + margin
    if isinstance(materials, Mapping):
        materials = Materials(**materials)
    stop = spin_stop if spin_stop is not None and spin_stop < duration else None
    end = duration if stop is None else stop
    reversing = spin_reverse is not None and spin_start < spin_reverse < end
    reverse = (spin_reverse,) if reversing else ()
    params = {
        "drum_radius": drum_radius,
        "length": length,
        "omega": omega,
        "fill_fraction": fill_fraction,
        "num_particles": int(num_particles),
        "particle_radius": particle_radius,
        "spin_start": spin_start,
        "spin_stop": spin_stop,
    }
    if reverse:  # only then: the params of drums that never reverse read as before
        params["spin_reverse"] = spin_reverse
    return Scene(
        name="drum",
        kind="drum",
        walls=[
            Wall(
                "drum",
                np.asarray(mesh.vertices),
                np.asarray(mesh.faces),
                WallMotion(
                    "rotation",
                    axis=(0.0, 1.0, 0.0),
                    omega=omega,
                    start_time=spin_start,
                    stop_time=stop,
                    reverse_times=reverse,
                ),
            )
        ],
        particles=particles,
        materials=materials or Materials(),
        domain_lo=(-ext, -length / 2 - margin, -ext),
        domain_hi=(ext, length / 2 + margin, ext),
        outflow_z=None,
        dem_dt=dem_dt,
        settle_time=settle_time,
        duration=duration,
        frame_dt=frame_dt,
        params=params,
    )
