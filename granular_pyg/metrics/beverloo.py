r"""Beverloo's mass flow rate through a hopper's outlet, and the outlet a Scene describes.

Beverloo's correlation (Beverloo, Leniger & van de Velde 1961) for a circular outlet of
diameter ``D`` and the slot form for a slot of width ``b`` and length ``L`` (Nedderman,
*Statics and Kinematics of Granular Materials*, 1992, ch. 10)::

    circle:     W = C_c rho_b sqrt(g) (D - k d)^{5/2}              C_c = 0.58
    slot:       W = C_s rho_b sqrt(g) L (b - k d)^{3/2}             C_s = 1.03
    rectangle:  W = C_s rho_b sqrt(g) (L - k d) (b - k d)^{3/2}

with ``k = 1.5`` (the empty annulus, in particle diameters ``d``), ``rho_b`` the bulk density
of the flowing bed (here ``0.6`` of the particle density, random loose packing, as the hopper
builder assumes) and ``g`` the magnitude of gravity. The slot form is for a slot that runs from
wall to wall (the built-in hopper's: its ends are the vertical walls, so no annulus there); the
rectangle form is for an orifice cut in a plate, with the annulus along all four edges.

These are correlations: with C and k from experiments on real grains, a DEM bed agrees to
within some 10-20%, which is why the rate is drawn as a reference line, not used as truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from granular_pyg.errors import InputError
from granular_pyg.scenes import Scene

__all__ = [
    "BULK_PACKING",
    "C_CIRCLE",
    "C_SLOT",
    "K_ANNULUS",
    "Outlet",
    "beverloo_rate",
    "outlet_of",
    "scene_beverloo_rate",
]

#: Beverloo's constant for a circular outlet.
C_CIRCLE = 0.58
#: The constant of the slot (and rectangle) form.
C_SLOT = 1.03
#: Width of the empty annulus, in particle diameters.
K_ANNULUS = 1.5
#: Bulk density of the flowing bed as a fraction of the particle density.
BULK_PACKING = 0.6
#: Isoperimetric quotient 4 pi A / P^2 above which an outlet's loop counts as a circle (a
#: regular 8-gon has 0.95, a square 0.785).
CIRCLE_QUOTIENT = 0.9


@dataclass(frozen=True)
class Outlet:
    """A hopper's outlet.

    Attributes:
        shape: ``"circle"``, ``"slot"`` (wall to wall: no annulus at its ends) or
            ``"rectangle"`` (an orifice in a plate).
        width: the circle's diameter, or the slot's / rectangle's short side ``b`` (m).
        length: the slot's / rectangle's long side ``L`` (m); the diameter for a circle.
        source: where it was read: ``"params"`` or ``"mesh"``.
    """

    shape: str
    width: float
    length: float
    source: str = "params"

    @property
    def area(self) -> float:
        """Open area (m^2)."""
        if self.shape == "circle":
            return math.pi * self.width**2 / 4.0
        return self.width * self.length


def beverloo_rate(
    outlet: Outlet,
    particle_diameter: float,
    particle_density: float,
    gravity: float = 9.81,
    packing: float = BULK_PACKING,
    k: float = K_ANNULUS,
) -> float:
    """Beverloo's mass flow rate (kg/s) through ``outlet`` (module docstring); 0 where the
    outlet is narrower than the annulus (``b <= k d``: no steady flow).

    Args:
        outlet: the outlet (m).
        particle_diameter: ``d`` (m).
        particle_density: solid density (kg/m^3); the bulk density is ``packing`` of it.
        gravity: ``|g|`` (m/s^2).
        packing: bulk solid fraction of the flowing bed.
        k: the annulus in particle diameters.
    """
    for name, value in (("particle_diameter", particle_diameter), ("gravity", gravity)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{name}: expected a positive number, got {value}")
    rho_b, sqrt_g = packing * particle_density, math.sqrt(gravity)
    b = outlet.width - k * particle_diameter
    if b <= 0:
        return 0.0
    if outlet.shape == "circle":
        return C_CIRCLE * rho_b * sqrt_g * b**2.5
    if outlet.shape == "slot":
        return C_SLOT * rho_b * sqrt_g * outlet.length * b**1.5
    if outlet.shape == "rectangle":
        return C_SLOT * rho_b * sqrt_g * max(outlet.length - k * particle_diameter, 0.0) * b**1.5
    raise InputError(f"outlet.shape: expected circle, slot or rectangle, got {outlet.shape!r}")


def outlet_of(scene: Scene, outlet_z: float | None = None) -> Outlet | None:
    """The outlet of a hopper Scene, or None where it cannot say.

    The built-in hopper (``params`` with ``opening`` and ``depth``) has a slot from wall to
    wall. Otherwise the outlet is read from the walls that stay (no removal time) at the
    outlet's opening: the smallest loop of open mesh edges lying in the plane ``z = outlet_z``
    (the hole the lid covered). Its area ``A`` and perimeter ``P`` give the shape: a circle of
    diameter ``4 A / P`` when ``4 pi A / P^2 > 0.9``, else the rectangle with that area and
    perimeter; None when no such loop exists or no rectangle fits it. Area and perimeter do not
    change when the scene is turned about the vertical or mirrored.

    Args:
        scene: the Scene.
        outlet_z: the outlet's height (m); default ``params["outlet_z"]`` (0 when absent).
    """
    params = scene.params or {}
    if "opening" in params and "depth" in params:
        return Outlet("slot", float(params["opening"]), float(params["depth"]), "params")
    if outlet_z is None:
        outlet_z = params.get("outlet_z")
        outlet_z = 0.0 if outlet_z is None else float(outlet_z)
    opened = scene.opening_time or 0.0
    kept = [w for w in scene.walls if w.removal_time is None]
    if not kept:
        return None
    loops = []
    for wall in kept:
        loops += _boundary_loops(wall.vertices_at(opened), wall.faces, outlet_z)
    if not loops:
        return None
    area, perimeter = min(loops)
    if area <= 0 or perimeter <= 0:
        return None
    if 4 * math.pi * area / perimeter**2 > CIRCLE_QUOTIENT:
        diameter = 4 * area / perimeter
        return Outlet("circle", diameter, diameter, "mesh")
    half = perimeter / 2  # b + L; b L = A
    disc = half**2 - 4 * area
    if disc < -1e-6 * half**2:
        return None
    root = math.sqrt(max(disc, 0.0))
    return Outlet("rectangle", (half - root) / 2, (half + root) / 2, "mesh")


def scene_beverloo_rate(scene: Scene, radii: np.ndarray, outlet_z: float | None = None) -> float:
    """Beverloo's rate (kg/s) for the Scene's outlet, materials and gravity and the particles'
    number-mean diameter ``2 mean(radii)`` (m); NaN where the outlet is unknown."""
    outlet = outlet_of(scene, outlet_z)
    radii = np.asarray(radii, dtype=np.float64)
    if outlet is None or radii.size == 0:
        return float("nan")
    g = float(np.linalg.norm(np.asarray(scene.gravity, dtype=np.float64)))
    return beverloo_rate(outlet, 2.0 * float(radii.mean()), scene.materials.density, g)


def _boundary_loops(vertices: np.ndarray, faces: np.ndarray, z: float) -> list[tuple[float, float]]:
    """``(area m^2, perimeter m)`` of each closed loop of open edges (edges of one triangle
    only) whose vertices all lie in the plane at height ``z`` (m); area projected on x-y."""
    vertices = np.asarray(vertices, dtype=np.float64)
    span = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
    tol = 1e-7 * max(span, 1e-3)
    # Coincident vertices are one (STL stores three per triangle).
    _, ids = np.unique(np.round(vertices / tol), axis=0, return_inverse=True)
    ids = ids.reshape(-1)
    points = np.zeros((ids.max() + 1, 3))
    points[ids] = vertices
    f = ids[np.asarray(faces)]
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    edges = edges[edges[:, 0] != edges[:, 1]]
    unique, count = np.unique(edges, axis=0, return_counts=True)
    flat = np.abs(points[:, 2] - z) <= 1e-6 * max(span, 1e-3)
    open_edges = unique[(count == 1) & flat[unique[:, 0]] & flat[unique[:, 1]]]
    neighbours: dict[int, list[int]] = {}
    for a, b in open_edges.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    loops, seen = [], set()
    for start in neighbours:
        if start in seen or len(neighbours[start]) != 2:
            continue
        loop, prev, here = [start], None, start
        seen.add(start)
        while True:
            nxt = [n for n in neighbours[here] if n != prev]
            if not nxt or len(neighbours[here]) != 2:
                loop = []
                break
            prev, here = here, nxt[0]
            if here == start:
                break
            if here in seen:
                loop = []
                break
            seen.add(here)
            loop.append(here)
        if len(loop) >= 3:
            xy = points[loop, :2]
            nxt_xy = np.roll(xy, -1, axis=0)
            area = 0.5 * abs(float(np.sum(xy[:, 0] * nxt_xy[:, 1] - nxt_xy[:, 0] * xy[:, 1])))
            perimeter = float(np.linalg.norm(nxt_xy - xy, axis=1).sum())
            loops.append((area, perimeter))
    return loops
