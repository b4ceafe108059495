"""The scene's own horizontal frame: a turn about gravity (maybe with a vertical mirror) read
off the walls, so that a model that is not equivariant sees every turned, mirrored or
re-meshed copy of a scene the same way.

:func:`canonical_frame` returns ``Q`` (``[3, 3]``, fixing z) with rows ``e1, e2, z``; the
scene seen in it has coordinates ``Q p``. It is *equivariant*: for any turn or mirror ``g``
about z, the frame of the scene moved by ``g`` is ``Q g^T``, so both copies look the same in
their frames (tested to 1e-9). Every quantity it reads is an exact surface integral over the
triangles, unchanged when a triangle is split into smaller ones of the same surface.

How the axes are chosen, first rule that decides:

1. **A wall that turns about a horizontal axis** (a drum): ``e2`` lies along the axis and the
   frame's handedness is chosen so that the drum turns about ``+e2`` (positive ``omega``),
   the sense of the drums of the training sets (axis y, ``omega > 0``). Turning the other way
   is the mirror image, which the frame undoes.
2. **Otherwise, the inclined walls' facing** (a hopper): ``e1`` is the main horizontal
   direction of the inclined walls' normals, ``sum |n_z| n_h n_h^T`` weighted by area (the
   wedge hoppers' inclined walls face +-x: their ``e1`` is x). Vertical and flat walls count
   for nothing.
3. **Otherwise, the walls' spread** (horizontal second moment of the surface), then the
   particles' spread about the walls' centre.

An axis still has two senses; each is the one along which the walls' surface (third moment,
then the particles' mean offset from the walls' centre) lies further. Where a rule cannot
decide (an axisymmetric cone, a symmetric wedge with a centred bed) it falls to the next;
where none can, the world axis is kept: the scene is then the same in either choice up to its
own symmetry.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # geometry does not import scenes at run time
    from granular_pyg.scenes.scene import Wall

__all__ = ["canonical_frame"]

#: A relative eigenvalue gap below this reads as "no main direction" (an axisymmetric part).
ISOTROPIC = 1e-3
#: A third moment (in units of the spread cubed) or mean offset (in units of the spread)
#: below this reads as "no preferred sense" (a mirror-symmetric part).
SYMMETRIC = 1e-4


def _triangles(walls: list[Wall]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every wall's triangles at its mesh pose: vertices ``[T, 3, 3]`` (m), areas ``[T]``
    (m^2) and unit normals ``[T, 3]``, degenerate triangles dropped."""
    tri = np.concatenate([w.vertices[w.faces] for w in walls])
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    twice = np.linalg.norm(cross, axis=1)
    keep = twice > 0
    return tri[keep], 0.5 * twice[keep], cross[keep] / twice[keep, None]


def _surface_moment(values: np.ndarray, area: np.ndarray, order: int) -> float:
    """``integral s^order dA`` over the triangles, ``s`` linear with vertex values
    ``values [T, 3]``: exact, ``2 A order! / (order + 2)! h_order(s0, s1, s2)`` summed."""
    s0, s1, s2 = values.T
    if order == 1:
        h = s0 + s1 + s2
    elif order == 2:
        h = s0**2 + s1**2 + s2**2 + s0 * s1 + s0 * s2 + s1 * s2
    else:  # 3
        h = (
            s0**3
            + s1**3
            + s2**3
            + s0**2 * (s1 + s2)
            + s1**2 * (s0 + s2)
            + s2**2 * (s0 + s1)
            + s0 * s1 * s2
        )
    factor = {1: 1.0 / 3.0, 2: 1.0 / 6.0, 3: 1.0 / 10.0}[order]
    return float(np.sum(factor * area * h))


def _main_direction(tensor: np.ndarray) -> np.ndarray | None:
    """The unit eigenvector ``[2]`` of the larger eigenvalue of a symmetric ``[2, 2]`` tensor,
    or None when the two eigenvalues are within ``ISOTROPIC`` of each other."""
    values, vectors = np.linalg.eigh(tensor)
    if values[1] <= 0 or (values[1] - values[0]) <= ISOTROPIC * (values[1] + values[0]):
        return None
    return vectors[:, 1]


class _Scene:
    """The integrals the rules read, about the walls' horizontal area centre."""

    def __init__(
        self, triangles: tuple[np.ndarray, np.ndarray, np.ndarray], points: np.ndarray | None
    ) -> None:
        tri, self.area, self.normal = triangles  # _triangles' vertices, areas, normals
        total = float(self.area.sum())
        centre = np.array([_surface_moment(tri[..., i], self.area, 1) for i in (0, 1)]) / total
        self.rel = tri[..., :2] - centre  # [T, 3, 2] horizontal, about the centre
        self.total = total
        xx = _surface_moment(self.rel[..., 0], self.area, 2)
        yy = _surface_moment(self.rel[..., 1], self.area, 2)
        xy = (_surface_moment(self.rel.sum(-1), self.area, 2) - xx - yy) / 2.0  # polarisation
        self.spread = np.array([[xx, xy], [xy, yy]])  # integral x_h x_h^T dA (m^4)
        self.scale = float(np.sqrt(max(np.trace(self.spread) / total, 1e-30)))  # m
        self.points = None
        if points is not None and len(points):
            self.points = np.asarray(points, np.float64)[:, :2] - centre

    def facing(self) -> np.ndarray:
        """``sum A |n_z| n_h n_h^T`` ``[2, 2]``: where the inclined walls face."""
        n_h = self.normal[:, :2]
        weight = self.area * np.abs(self.normal[:, 2])
        return (n_h * weight[:, None]).T @ n_h

    def point_spread(self) -> np.ndarray | None:
        """The bed's horizontal second moment ``[2, 2]`` (m^2) about the walls' centre, or
        None without particles."""
        if self.points is None:
            return None
        return self.points.T @ self.points / len(self.points)

    def sense(self, direction: np.ndarray) -> float:
        """+1 or -1: the sense of ``direction`` ``[2]`` along which the surface lies further
        (third moment), else the particles' mean offset; 0 when neither decides."""
        third = _surface_moment(self.rel @ direction, self.area, 3)
        if abs(third) > SYMMETRIC * self.total * self.scale**3:
            return float(np.sign(third))
        if self.points is not None:
            offset = float(np.mean(self.points @ direction))
            if abs(offset) > SYMMETRIC * self.scale:
                return float(np.sign(offset))
        return 0.0


def _turning_axis(walls: list[Wall]) -> np.ndarray | None:
    """``omega``'s direction ``[2]`` (horizontal, unit, right-hand rule) of the largest wall that
    turns about a mostly horizontal axis, or None."""
    best, best_area = None, -1.0
    for wall in walls:
        m = wall.motion
        axis = np.asarray(m.axis, np.float64)
        axis = axis / np.linalg.norm(axis)
        if m.kind != "rotation" or m.omega == 0 or np.linalg.norm(axis[:2]) < 0.5:
            continue
        area = float(_triangles([wall])[1].sum())
        if area > best_area:
            best, best_area = np.sign(m.omega) * axis[:2] / np.linalg.norm(axis[:2]), area
    return best


def _frame(e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    q = np.eye(3)
    q[0, :2], q[1, :2] = e1, e2
    return q


def canonical_frame(walls: list[Wall], points: np.ndarray | None = None) -> np.ndarray:
    """The scene's own frame ``Q`` ``[3, 3]`` (float64, orthogonal, fixing z; see the module).

    Args:
        walls: the scene's walls (their mesh poses and motions; removal times do not matter).
        points: ``[N, 3]`` particle centres (m) that break a tie the walls leave (a symmetric
            wedge: which side the bed leans to), or None.

    Returns:
        ``Q`` such that the scene turned by ``g`` has the frame ``Q g^T``.
    """
    triangles = _triangles(walls) if walls else None
    if triangles is None or not len(triangles[1]):  # no surface to read a frame off
        return np.eye(3)
    scene = _Scene(triangles, points)
    omega = _turning_axis(walls)
    if omega is not None:
        # e2 along the axis, its sense from the walls or the bed (omega itself is a
        # pseudovector: it cannot pick a sense that survives a mirror)
        sense = scene.sense(omega)
        e2 = (sense if sense else 1.0) * omega
        e1 = np.array([e2[1], -e2[0]])  # e2 x z: det(Q) = +1
        # the drum turns about +e2 in the frame: det(Q) (e2 . omega) > 0
        if float(e2 @ omega) < 0:
            e1 = -e1
        return _frame(e1, e2)
    for tensor in (scene.facing(), scene.spread, scene.point_spread()):
        main = None if tensor is None else _main_direction(tensor)
        if main is not None:
            break
    else:
        main = np.array([1.0, 0.0])
    other = np.array([-main[1], main[0]])
    axes = []
    for axis in (main, other):
        sense = scene.sense(axis)
        axes.append((sense if sense else 1.0) * axis)
    return _frame(*axes)
