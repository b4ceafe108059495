"""The walls of a Scene as the learned simulator queries them, at any recorded time."""

from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numpy as np
import torch

from granular_pyg.errors import InputError
from granular_pyg.geometry import (
    SegmentCrossings,
    WallIndex,
    argmin_per_group,
    segment_triangle_crossings,
    surface_patches,
    triangle_normals,
)
from granular_pyg.scenes.scene import Scene, Wall

__all__ = ["WallContacts", "WallSet"]

#: Correction passes of :meth:`WallSet.contain` before a particle is held where it was (a
#: corner can need one pass per wall it meets).
CONTAIN_PASSES = 4

#: The guard's skin as a fraction of its margin: a move that ends closer than this to a wall's
#: plane is corrected too, and a corrected centre keeps at least twice this from the plane.
#: Without it a centre crept up to a wall (each correction keeping the start's distance) ends
#: on the plane, where round-off puts it on either side (measured: a drum particle through its
#: shell after 27 steps riding it).
GUARD_SKIN = 1e-3


class WallContacts(NamedTuple):
    """Particle-triangle pairs closer than a radius at one time, world frame.

    Attributes:
        point_idx: ``[K]`` int64 index of the particle.
        tri_idx: ``[K]`` int64 triangle index, global over the WallSet's walls.
        closest: ``[K, 3]`` closest point on the triangle (m).
        normal: ``[K, 3]`` the triangle's unit normal from its vertex order (right-hand rule).
        velocity: ``[K, 3]`` the wall's velocity at the closest point (m/s).
    """

    point_idx: torch.Tensor
    tri_idx: torch.Tensor
    closest: torch.Tensor
    normal: torch.Tensor
    velocity: torch.Tensor


class WallSet:
    """One :class:`~granular_pyg.geometry.WallIndex` per wall, built once; poses, removals and
    wall velocities follow the walls' motions at the query time (every
    :class:`~granular_pyg.scenes.WallMotion` kind: rotation, translation, oscillation).

    Args:
        walls: a Scene or its list of walls.
    """

    def __init__(self, walls: Scene | list[Wall]) -> None:
        self.walls = list(walls.walls if isinstance(walls, Scene) else walls)
        self.indices = [
            WallIndex(torch.from_numpy(w.vertices), torch.from_numpy(w.faces)) for w in self.walls
        ]
        self.normals = [triangle_normals(index.triangles) for index in self.indices]  # mesh frame
        counts = [len(w.faces) for w in self.walls]
        self.offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
        self.num_triangles = int(sum(counts))

    @cached_property
    def _patches(self) -> tuple[torch.Tensor, int]:
        """Grouped once, on first use (only models with a node per patch ask)."""
        patches, first = [], 0
        for w in self.walls:  # patches never span two walls (each has its own motion)
            ids = surface_patches(w.vertices, w.faces)
            patches.append(ids + first)
            first += int(ids.max()) + 1 if len(ids) else 0
        return torch.from_numpy(np.concatenate(patches or [np.zeros(0, np.int64)])), first

    @property
    def patch_of(self) -> torch.Tensor:
        """``[T]`` int64 surface patch of each triangle, global over the walls
        (:func:`~granular_pyg.geometry.surface_patches`)."""
        return self._patches[0]

    @property
    def num_patches(self) -> int:
        """Number of surface patches over the walls."""
        return self._patches[1]

    def __repr__(self) -> str:
        names = ", ".join(f"{w.name}: {len(w.faces)}" for w in self.walls)
        return f"WallSet({names})"

    @staticmethod
    def _events(wall: Wall) -> list[float]:
        """Times (s) at which ``wall`` is removed or its motion starts, stops or reverses."""
        m = wall.motion
        events = [] if wall.removal_time is None else [wall.removal_time]
        if m.kind != "static":
            events += [m.start_time, *m.reverse_times]
            if m.stop_time is not None:
                events.append(m.stop_time)
        return events

    def event_times(self) -> list[float]:
        """Sorted times (s) of every wall's events (removal; motion start, stop, reversal)."""
        return sorted({float(e) for wall in self.walls for e in self._events(wall)})

    def moving(self, t0: float, t1: float) -> list[int]:
        """Indices of the walls in motion at some time within ``(t0, t1)`` (s)."""
        return [
            i
            for i, wall in enumerate(self.walls)
            if wall.motion.kind != "static"
            and wall.motion.start_time < t1
            and (wall.motion.stop_time is None or wall.motion.stop_time > t0)
        ]

    def changing(self, t0: float, t1: float) -> list[int]:
        """Indices of the walls removed, or whose motion starts, stops or reverses, at a
        recorded time in ``[t0, t1]`` (s, to 1 ns: recorded times are sums of frame spacings):
        the events a learned step over it holds."""
        return [
            i
            for i, wall in enumerate(self.walls)
            if any(t0 - 1e-9 <= e <= t1 + 1e-9 for e in self._events(wall))
        ]

    def near(
        self, points: torch.Tensor, reach: float, time: float, walls: list[int]
    ) -> torch.Tensor:
        """``[P]`` bool: the ``points [P, 3]`` (m) closer than ``reach`` (m) to a triangle of
        one of ``walls`` (indices), at the walls' poses at recorded time ``time`` (s)."""
        near = torch.zeros(points.shape[0], dtype=torch.bool)
        for i in walls:
            rot, shift = self.walls[i].motion.pose(time)
            found = self.indices[i].pairs(
                points.detach().cpu(),
                reach,
                torch.from_numpy(rot).to(points.dtype),
                torch.from_numpy(shift).to(points.dtype),
            )
            near[found.point_idx] = True
        return near

    def contacts(
        self, points: torch.Tensor, radius: float, time: float, step_end: float | None = None
    ) -> WallContacts:
        """Every (particle, triangle) pair closer than ``radius`` among the walls present,
        sorted by wall, then particle, then triangle.

        Args:
            points: ``[P, 3]`` world positions (m), float32 or float64.
            radius: cut-off (m).
            time: recorded time (s) that sets each wall's pose.
            step_end: None: the walls present at ``time``, with their velocities at ``time``.
                A later time (s): the walls as a learned step from ``time`` to ``step_end``
                sees them, those present over the whole step (to 1 ns: a wall removed at
                ``step_end`` counts) with their mean velocities over the step (a lid removed,
                a drum started or stopped during the step shows).
        """
        over_step = step_end is not None and step_end > time
        # Over a step: the walls there for all of it (one removed at its very end held the bed
        # for the whole step: the truth has not moved yet); at ``time`` otherwise.
        present_time = step_end - 1e-9 if over_step else time
        dtype = points.dtype
        parts = []
        for wall, index, normals, offset in zip(
            self.walls, self.indices, self.normals, self.offsets, strict=True
        ):
            if not wall.present(present_time):
                continue
            rot_np, shift_np = wall.motion.pose(time)
            rot = torch.from_numpy(rot_np).to(dtype)
            shift = torch.from_numpy(shift_np).to(dtype)
            found = index.pairs(points, radius, rot, shift)
            normal = normals[found.tri_idx].to(dtype) @ rot.T
            velocity = torch.zeros_like(found.closest)
            m = wall.motion
            if m.kind == "rotation":
                rate = (
                    m.mean_angular_velocity(time, step_end)
                    if over_step
                    else m.angular_velocity(time)
                )
                if rate != 0.0:
                    axis = torch.tensor(m.axis, dtype=dtype)
                    omega = rate * axis / torch.linalg.vector_norm(axis)
                    arm = found.closest - torch.tensor(m.origin, dtype=dtype)
                    velocity = torch.linalg.cross(omega.expand_as(arm), arm)
            elif m.kind in ("translation", "oscillation"):
                # A rigid shift: every point of the wall moves with the same velocity.
                rate = (
                    m.mean_linear_velocity(time, step_end) if over_step else m.linear_velocity(time)
                )
                velocity = torch.from_numpy(rate).to(dtype).expand_as(found.closest).clone()
            parts.append((found.point_idx, found.tri_idx + offset, found.closest, normal, velocity))
        if not parts:
            empty = torch.zeros(0, dtype=torch.int64)
            vec = points.new_zeros((0, 3))
            return WallContacts(empty, empty.clone(), vec, vec.clone(), vec.clone())
        return WallContacts(*(torch.cat(cols) for cols in zip(*parts, strict=True)))

    def contain(
        self,
        start: torch.Tensor,
        end: torch.Tensor,
        start_time: float,
        end_time: float,
        margin: torch.Tensor | float,
        radius: float,
    ) -> tuple[torch.Tensor, int]:
        """The wall guard: moves that would carry a particle centre through a wall end before it.

        A move ``start -> end`` that crosses a triangle of a wall present at ``end_time`` (the
        start posed at ``start_time``, the end at ``end_time``, so a rotating drum is followed
        exactly) is cut at that wall: the end keeps its motion along the wall and is put back on
        the start's side, ``min(margin, start's distance from the wall)`` from its plane (an
        inelastic, frictionless contact), but never closer than ``2 * GUARD_SKIN * margin``;
        a move that ends closer than ``GUARD_SKIN * margin`` counts as crossing (so round-off
        cannot carry a centre that rides a wall through it). The first crossing along the move
        is corrected first; up to :data:`CONTAIN_PASSES` passes resolve corners, after which a
        particle that still crosses stays at ``start``.

        Args:
            start: ``[P, 3]`` positions at ``start_time`` (m, world frame).
            end: ``[P, 3]`` proposed positions at ``end_time`` (m).
            start_time: recorded time of ``start`` (s).
            end_time: recorded time of ``end`` (s).
            margin: ``[P]`` or a float, > 0 (m): how close to a wall a corrected centre ends,
                usually the particle radius.
            radius: the smallest wall-index query radius (m); longer moves query with it
                times a power of two. The simulator passes its cut-off, whose grids the wall
                nodes have built already.

        Returns:
            ``(end [P, 3], corrected)``: the contained positions in the dtype of ``end`` and the
            number of particles that were moved back.
        """
        dtype = end.dtype
        p0, p1 = start.double(), end.double()
        margin = torch.as_tensor(margin, dtype=torch.float64).expand(p1.shape[0])
        if not bool((margin > 0).all()):
            raise InputError("margin: the wall guard needs a positive distance (m) per particle")
        corrected = torch.zeros(p1.shape[0], dtype=torch.bool)
        active = torch.arange(p1.shape[0])  # only corrected moves can cross anew
        for passes in range(CONTAIN_PASSES + 1):
            fixed = self._first_crossing_fix(
                p0[active], p1[active], start_time, end_time, margin[active], float(radius)
            )
            if fixed is None:
                break
            rows = active[fixed[0]]
            if passes == CONTAIN_PASSES:
                p1[rows] = p0[rows]
                break
            p1[rows] = fixed[1]
            corrected[rows] = True
            active = rows
        return p1.to(dtype), int(corrected.sum())

    def crossings(
        self,
        start: torch.Tensor,
        end: torch.Tensor,
        start_time: float,
        end_time: float,
        radius: float | None = None,
    ) -> torch.Tensor:
        """Which moves ``start -> end`` carry a centre through a wall present at ``end_time``.

        The test of :meth:`contain` without its skin and without correcting anything: the start
        is posed at ``start_time`` and the end at ``end_time`` (a centre carried along by a
        rotating drum never crosses it), only the triangles near each move are tested (the
        wall index's candidates), and a move crosses a triangle when it starts off its plane
        and ends on it or past it, through the triangle or its edges
        (:func:`~granular_pyg.geometry.segment_triangle_crossings`). Rows with NaN never cross.

        Args:
            start: ``[P, 3]`` positions at ``start_time`` (m, world frame).
            end: ``[P, 3]`` positions at ``end_time`` (m).
            start_time: recorded time of ``start`` (s).
            end_time: recorded time of ``end`` (s); the walls present then count.
            radius: the smallest wall-index query radius (m), longer moves query with it times
                a power of two; default 1/64 of the walls' bounding-box diagonal.

        Returns:
            ``[P]`` bool (the test runs in float64 whatever the inputs' dtype).
        """
        p0, p1 = start.double(), end.double()
        crossed = torch.zeros(p0.shape[0], dtype=torch.bool)
        rows = (torch.isfinite(p0).all(1) & torch.isfinite(p1).all(1)).nonzero().squeeze(1)
        if rows.numel() == 0 or not self.walls:
            return crossed
        base = self._default_radius() if radius is None else float(radius)
        no_skin = torch.zeros(rows.numel(), dtype=torch.float64)
        for cand, _, _ in self._crossing_pairs(
            p0[rows], p1[rows], start_time, end_time, no_skin, base
        ):
            crossed[rows[cand]] = True
        return crossed

    def _default_radius(self) -> float:
        """1/64 of the diagonal of the walls' bounding box in their mesh frames (m), computed
        once."""
        if getattr(self, "_crossing_radius", None) is None:
            points = torch.cat([index.vertices.double() for index in self.indices])
            diagonal = float(torch.linalg.vector_norm(points.max(0).values - points.min(0).values))
            self._crossing_radius = diagonal / 64 if diagonal > 0 else 1.0
        return self._crossing_radius

    def _first_crossing_fix(self, p0, p1, t0, t1, margin, base):
        """``(rows, corrected ends)`` of the particles whose move crosses a wall, or None."""
        found = []  # (particle, fraction along the move, corrected end in the world frame)
        for cand, hit, (q1, rot1, shift1) in self._crossing_pairs(
            p0, p1, t0, t1, GUARD_SKIN * margin, base
        ):
            gap = torch.minimum(hit.start_distance, margin[cand])
            gap = torch.maximum(gap, 2 * GUARD_SKIN * margin[cand])
            push = (gap + hit.end_depth).unsqueeze(1) * hit.normal
            found.append((cand, hit.fraction, (q1[cand] + push) @ rot1.T + shift1))
        if not found:
            return None
        cand, frac, moved = (torch.cat(col) for col in zip(*found, strict=True))
        rows, first = argmin_per_group(frac, cand)  # each particle's first crossing
        return rows, moved[first]

    def _crossing_pairs(self, p0, p1, t0, t1, skin, base):
        """The (move, triangle) pairs whose move crosses the triangle, wall by wall.

        Moves ``p0 [P, 3] -> p1 [P, 3]`` (float64, world frame, finite) against the walls
        present at ``t1``, the start posed at ``t0`` and the end at ``t1``; ``skin [P]`` (m) as
        in :func:`~granular_pyg.geometry.segment_triangle_crossings`; ``base`` the smallest
        wall-index query radius (m).

        Yields:
            ``(rows [K], crossings, (q1 [P, 3], rot1, shift1))``: the moves' rows, their
            :class:`~granular_pyg.geometry.SegmentCrossings` (crossing pairs only) and the
            wall's mesh-frame ends and pose at ``t1``.
        """
        for wall, index, normals in zip(self.walls, self.indices, self.normals, strict=True):
            if not wall.present(t1):
                continue
            rot0, shift0 = (torch.from_numpy(x) for x in wall.motion.pose(t0))
            rot1, shift1 = (torch.from_numpy(x) for x in wall.motion.pose(t1))
            q0, q1 = (p0 - shift0) @ rot0, (p1 - shift1) @ rot1  # mesh frame
            reach = torch.linalg.vector_norm(q1 - q0, dim=1)
            # Triangles a move crosses lie within its length of its end: query in powers of two.
            level = torch.ceil(torch.log2(torch.clamp(reach / base, min=1.0))).long()
            for lv in torch.unique(level).tolist():
                rows = (level == lv).nonzero().squeeze(1)
                cand, tri = index.candidates(q1[rows], base * 2.0**lv)
                cand = rows[cand]
                # Only pairs whose move ends on or past the triangle's plane can cross it.
                origin, normal = index.triangles[tri, 0].double(), normals[tri].double()
                a = ((q0[cand] - origin) * normal).sum(1)
                b = ((q1[cand] - origin) * normal).sum(1)
                side = (a != 0) & (torch.sign(a) * b <= skin[cand])
                cand, tri = cand[side], tri[side]
                if cand.numel() == 0:
                    continue
                hit = segment_triangle_crossings(
                    q0[cand], q1[cand], index.triangles.double()[tri], skin[cand]
                )
                sel = hit.crosses
                if bool(sel.any()):
                    yield cand[sel], SegmentCrossings(*(x[sel] for x in hit)), (q1, rot1, shift1)
