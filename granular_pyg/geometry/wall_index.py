"""Spatial index for "which triangles are within a radius of which points" (wall culling).

The dense approach (BGNN) evaluates every particle against every triangle, ``O(P * F)`` per
step. :class:`WallIndex` instead bins the mesh once into a uniform grid whose cells list the
triangles that can come within the query radius of any point in the cell (a conservative,
exact-distance test against the cell's bounding sphere, so a large slanted triangle is listed
only in the cells along its surface, not in its whole bounding box). A query looks up one cell
per point, then computes exact distances for the listed candidates only: its cost grows with the
number of near pairs, not with ``points x triangles``. Both the grid build and the query first
drop the pairs that two cheap lower bounds on the distance already rule out (the distance to
the triangle's plane and to its bounding sphere), so the exact closest-point test runs only on
the pairs that may pass it.

A rigidly moving mesh is queried by mapping the points into the mesh frame; the grid is never
rebuilt. Grids are built per radius on first use and cached (a simulator uses one radius).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch

from granular_pyg.errors import InputError, check_tensor
from granular_pyg.geometry.closest_point import closest_point_on_triangles

__all__ = ["WallIndex", "WallPairs", "dense_wall_pairs"]

# Relative slack on the cell test, so float round-off never drops a true pair.
_CELL_SLACK = 1e-6
# A triangle whose doubled area is below this fraction of its longest edge squared is too thin
# for its computed normal to bound the distance: its plane bound is left out (set to 0).
_THIN = 1e-6
# Smallest grid cell as a fraction of the median triangle edge (see WallIndex's cell_size).
_MIN_CELL_OF_EDGE = 0.125
# Boxes of at most this many cells stop being halved: their cells are listed and tested at once.
_SMALL_BOX = 64


def _check_radius(radius) -> float:
    try:
        value = float(radius)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"radius: expected a finite number > 0 (m), got {radius!r}")
    return value


class WallPairs(NamedTuple):
    """Point-triangle pairs closer than a radius, sorted by ``(point_idx, tri_idx)``.

    Attributes:
        point_idx: ``[K]`` int64 index into the query points.
        tri_idx: ``[K]`` int64 index into the mesh's faces.
        closest: ``[K, 3]`` closest point on the triangle, world frame (m).
        sq_dist: ``[K]`` squared distance point-to-triangle (m^2), ``< radius**2``.
    """

    point_idx: torch.Tensor
    tri_idx: torch.Tensor
    closest: torch.Tensor
    sq_dist: torch.Tensor


@dataclass(frozen=True)
class _Grid:
    origin: torch.Tensor  # [3] float64, corner of cell (0, 0, 0) in the mesh frame
    cell_size: float  # m
    dims: tuple[int, int, int]
    cell_start: torch.Tensor  # [num_cells + 1] int64, CSR offsets into cell_tris
    cell_tris: torch.Tensor  # [E] int64 triangle ids, ascending within a cell


@dataclass(frozen=True)
class _Bounds:
    """Per-triangle data of two cheap lower bounds on a point's distance to a triangle."""

    normal: torch.Tensor  # [F, 3] unit normal; 0 for a thin triangle (no plane bound)
    anchor: torch.Tensor  # [F, 3] vertex 0 (m)
    centre: torch.Tensor  # [F, 3] centroid (m)
    spread: torch.Tensor  # [F] largest vertex distance from the centroid (m)
    slack: float  # m: round-off allowance of the bounds in this dtype

    @classmethod
    def of(cls, tris: torch.Tensor, dtype: torch.dtype) -> _Bounds:
        """Bounds of ``tris [F, 3, 3]`` (float64), stored in ``dtype``."""
        v0, v1, v2 = tris.unbind(dim=1)
        cross = torch.linalg.cross(v1 - v0, v2 - v0)
        area2 = torch.linalg.vector_norm(cross, dim=1, keepdim=True)
        edge2 = torch.stack([(v1 - v0), (v2 - v1), (v0 - v2)]).square().sum(-1).amax(0)
        usable = area2.squeeze(1) > _THIN * edge2
        normal = torch.where(usable[:, None], cross / area2.clamp_min(1e-300), 0.0)
        centre = tris.mean(dim=1)
        spread = torch.linalg.vector_norm(tris - centre[:, None], dim=2).amax(dim=1)
        scale = float(tris.abs().max()) if tris.numel() else 1.0
        slack = 64 * torch.finfo(dtype).eps * max(scale, 1e-3)
        return cls(normal.to(dtype), v0.to(dtype), centre.to(dtype), spread.to(dtype), slack)

    def lower(self, points: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
        """``[K]`` a lower bound (m) on the distance of ``points [K, 3]`` to triangles
        ``tri [K]``: the larger of the plane distance and the bounding-sphere distance."""
        plane = ((points - self.anchor[tri]) * self.normal[tri]).sum(dim=1).abs()
        sphere = torch.linalg.vector_norm(points - self.centre[tri], dim=1) - self.spread[tri]
        return torch.maximum(plane, sphere)


class WallIndex:
    """Uniform-grid index over a triangle mesh for radius queries.

    Args:
        vertices: ``[V, 3]`` float vertex positions in the mesh frame (m).
        faces: ``[F, 3]`` integer vertex indices.
        cell_size: grid cell edge (m) as a multiple of the query radius; 1.0 by default. Cells
            are never smaller than :data:`_MIN_CELL_OF_EDGE` of the median triangle edge: a
            query radius far below the triangles' size (the training noise's wall check,
            1e-6 m) would otherwise build millions of cells (10 M, 80 MB and several seconds
            for the bundled hopper) for no less work per query.
        max_cells: cap on grid cells; cells grow beyond ``cell_size`` to respect it.

    Raises:
        InputError: on bad shapes, NaN/Inf vertices, face indices out of range or an empty mesh.
    """

    def __init__(
        self,
        vertices: torch.Tensor,
        faces: torch.Tensor,
        *,
        cell_size: float = 1.0,
        max_cells: int = 1 << 24,
    ) -> None:
        check_tensor("vertices", vertices, (None, 3))
        check_tensor("faces", faces, (None, 3), floating=False)
        if faces.dtype.is_floating_point or faces.dtype == torch.bool:
            raise InputError(f"faces: expected an integer tensor, got {faces.dtype}")
        if faces.shape[0] == 0:
            raise InputError("faces: the mesh has no triangles; give at least one face")
        if int(faces.min()) < 0 or int(faces.max()) >= vertices.shape[0]:
            raise InputError(
                f"faces: indices must lie in [0, {vertices.shape[0] - 1}], "
                f"got [{int(faces.min())}, {int(faces.max())}]"
            )
        if not cell_size > 0:
            raise InputError(f"cell_size: must be > 0, got {cell_size}")
        self.vertices = vertices
        self.faces = faces.long()
        self.triangles = vertices[self.faces]  # [F, 3, 3]
        self.cell_size_factor = float(cell_size)
        self.max_cells = int(max_cells)
        self._grids: dict[float, _Grid] = {}
        self._triangles_by_dtype = {vertices.dtype: self.triangles}
        self._bounds_by_dtype: dict[torch.dtype, _Bounds] = {}
        corners = self.triangles.double()
        edges = corners - corners.roll(1, dims=1)
        lengths = torch.linalg.vector_norm(edges, dim=2).flatten()
        lengths = lengths[lengths > 0]
        self.min_cell = _MIN_CELL_OF_EDGE * float(lengths.median()) if len(lengths) else 0.0

    @property
    def num_triangles(self) -> int:
        return self.faces.shape[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(triangles={self.num_triangles})"

    def query(
        self,
        points: torch.Tensor,
        radius: float,
        rotation: torch.Tensor | None = None,
        translation: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Pairs (point, triangle) with distance ``< radius``; see :meth:`pairs`.

        Returns:
            ``(point_idx [K], tri_idx [K])`` int64, sorted by point then triangle.
        """
        found = self.pairs(points, radius, rotation, translation)
        return found.point_idx, found.tri_idx

    def pairs(
        self,
        points: torch.Tensor,
        radius: float,
        rotation: torch.Tensor | None = None,
        translation: torch.Tensor | None = None,
    ) -> WallPairs:
        """Every (point, triangle) pair closer than ``radius``, with the closest points.

        Args:
            points: ``[P, 3]`` world-frame positions (m), float32 or float64.
            radius: cut-off distance (m), > 0.
            rotation: ``[3, 3]`` mesh pose, ``x_world = rotation @ x_mesh + translation``;
                identity when omitted.
            translation: ``[3]`` mesh pose translation (m); zero when omitted.

        Returns:
            :class:`WallPairs` sorted by ``(point_idx, tri_idx)``; closest points in the world
            frame, in the dtype of ``points``.
        """
        radius = _check_radius(radius)
        local = self._to_mesh_frame(points, rotation, translation)
        point_idx, tri_idx = self._candidates(local, radius)
        near = local[point_idx]
        bounds = self._bounds_as(local.dtype)
        maybe = bounds.lower(near, tri_idx) < radius + bounds.slack
        point_idx, tri_idx, near = point_idx[maybe], tri_idx[maybe], near[maybe]
        closest, sq_dist = closest_point_on_triangles(
            near, self._triangles_as(points.dtype)[tri_idx], validate=False
        )
        keep = sq_dist < radius**2
        closest = closest[keep]
        if rotation is not None or translation is not None:
            closest = self._to_world_frame(closest, rotation, translation)
        return WallPairs(point_idx[keep], tri_idx[keep], closest, sq_dist[keep])

    def candidates(
        self,
        points: torch.Tensor,
        radius: float,
        rotation: torch.Tensor | None = None,
        translation: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The candidate pairs the grid proposes before exact distances (a superset of
        :meth:`query`); their number is the work a query does.

        Returns:
            ``(point_idx [C], tri_idx [C])`` int64, sorted by point then triangle.
        """
        return self._candidates(self._to_mesh_frame(points, rotation, translation), radius)

    def _candidates(self, local: torch.Tensor, radius: float):
        grid = self._grid(_check_radius(radius))
        device = local.device
        cell = torch.floor((local.double() - grid.origin) / grid.cell_size).long()
        dims = torch.tensor(grid.dims, device=device)
        valid = ((cell >= 0) & (cell < dims)).all(dim=1)
        cell_id = cell[:, 0] + grid.dims[0] * (cell[:, 1] + grid.dims[1] * cell[:, 2])
        cell_id = torch.where(valid, cell_id, 0)
        start = grid.cell_start[cell_id]
        count = torch.where(valid, grid.cell_start[cell_id + 1] - start, 0)

        point_idx = torch.repeat_interleave(torch.arange(local.shape[0], device=device), count)
        first = torch.cumsum(count, 0) - count  # exclusive prefix sum
        within = torch.arange(point_idx.shape[0], device=device) - torch.repeat_interleave(
            first, count
        )
        tri_idx = grid.cell_tris[torch.repeat_interleave(start, count) + within]
        return point_idx, tri_idx

    def _bounds_as(self, dtype: torch.dtype) -> _Bounds:
        if dtype not in self._bounds_by_dtype:
            self._bounds_by_dtype[dtype] = _Bounds.of(self.triangles.double(), dtype)
        return self._bounds_by_dtype[dtype]

    def _triangles_as(self, dtype: torch.dtype) -> torch.Tensor:
        if dtype not in self._triangles_by_dtype:
            self._triangles_by_dtype[dtype] = self.triangles.to(dtype)
        return self._triangles_by_dtype[dtype]

    # -- frames -------------------------------------------------------------------------------

    @staticmethod
    def _pose(points, rotation, translation):
        rot = None if rotation is None else rotation.to(points.dtype)
        shift = None if translation is None else translation.to(points.dtype)
        if rot is not None:
            check_tensor("rotation", rot, (3, 3))
        if shift is not None:
            check_tensor("translation", shift, (3,))
        return rot, shift

    def _to_mesh_frame(self, points, rotation, translation):
        check_tensor("points", points, (None, 3))
        rot, shift = self._pose(points, rotation, translation)
        local = points if shift is None else points - shift
        return local if rot is None else local @ rot  # rows: R^T (p - t)

    def _to_world_frame(self, local, rotation, translation):
        rot, shift = self._pose(local, rotation, translation)
        world = local if rot is None else local @ rot.T
        return world if shift is None else world + shift

    # -- grid ---------------------------------------------------------------------------------

    def _grid(self, radius: float) -> _Grid:
        if radius not in self._grids:
            self._grids[radius] = self._build_grid(radius)
        return self._grids[radius]

    def _build_grid(self, radius: float) -> _Grid:
        tris = self.triangles.double()
        flat = tris.reshape(-1, 3)
        lo, hi = flat.min(dim=0).values, flat.max(dim=0).values
        h = max(radius * self.cell_size_factor, self.min_cell)
        # Cells needed so that any point within `radius` of the mesh falls inside the grid.
        while True:
            origin = lo - radius - h
            dims = tuple(int(d) for d in torch.ceil((hi + radius + h - origin) / h).tolist())
            if math.prod(dims) <= self.max_cells:
                break
            h *= 1.25
        cell, tri_id = self._cells_near_triangles(tris, origin, h, radius)
        cell_id = cell[:, 0] + dims[0] * (cell[:, 1] + dims[1] * cell[:, 2])
        key = (cell_id * self.num_triangles + tri_id).sort().values  # by cell, then triangle
        cell_id, tri_id = key // self.num_triangles, key % self.num_triangles
        num_cells = math.prod(dims)
        cell_start = torch.zeros(num_cells + 1, dtype=torch.int64, device=tris.device)
        cell_start[1:] = torch.cumsum(torch.bincount(cell_id, minlength=num_cells), 0)
        return _Grid(origin, h, dims, cell_start, tri_id)

    def _cells_near_triangles(self, tris, origin, h, radius):
        r"""Every (cell, triangle) with :math:`d(\text{centre}, T) \le r + \tfrac{\sqrt3}{2} h`.

        Any point of such a cell within ``radius`` of ``T`` makes the cell pass, so the list is
        conservative. Boxes of cells start as each triangle's bounding box expanded by the
        radius and are halved along their longest side until they hold at most
        :data:`_SMALL_BOX` cells, keeping a half only if it may hold a passing cell: a box of
        ``s`` cells keeps iff
        :math:`d(\text{centre}, T) \le r + \tfrac{\sqrt3}{2} h + \tfrac{h}{2} |s - 1|`
        (the farthest cell centre lies :math:`\tfrac{h}{2}|s - 1|` from the box centre). Boxes
        are tested with the cheap lower bounds of :class:`_Bounds`, the cells of the small boxes
        at the end with the bounds and then the exact distance. The work follows the cells
        along the surface, not the bounding boxes' volume.

        Returns:
            ``(cell_xyz [E, 3] int64, tri_id [E] int64)``.
        """
        tri = torch.arange(self.num_triangles, device=tris.device)
        lo = torch.floor((tris.min(dim=1).values - radius - origin) / h).long()
        hi = torch.floor((tris.max(dim=1).values + radius - origin) / h).long()
        cell_reach = radius + 0.5 * math.sqrt(3.0) * h
        bounds = self._bounds_as(torch.float64)
        while True:
            size = hi - lo + 1
            centre = origin + 0.5 * (lo + hi + 1).double() * h
            reach = cell_reach + 0.5 * h * torch.linalg.vector_norm((size - 1).double(), dim=1)
            keep = bounds.lower(centre, tri) <= reach * (1.0 + _CELL_SLACK) + bounds.slack
            tri, lo, size = tri[keep], lo[keep], size[keep]
            split = size.prod(dim=1) > _SMALL_BOX
            if not bool(split.any()):
                break
            hi = hi[keep]
            # Halve every box of more than _SMALL_BOX cells along its longest side.
            axis = size.argmax(dim=1, keepdim=True)
            mid = lo.gather(1, axis) + size.gather(1, axis) // 2
            lo_b, hi_a = lo.clone(), hi.clone()
            lo_b.scatter_(1, axis, mid)
            hi_a.scatter_(1, axis, mid - 1)
            tri = torch.cat([tri[~split], tri[split], tri[split]])
            lo, hi = (
                torch.cat([lo[~split], lo[split], lo_b[split]]),
                torch.cat([hi[~split], hi_a[split], hi[split]]),
            )
        # Every cell of the small boxes that remain: the bounds, then the exact test.
        count = size.prod(dim=1)
        box = torch.repeat_interleave(torch.arange(len(tri), device=tris.device), count)
        within = torch.arange(len(box), device=tris.device) - (torch.cumsum(count, 0) - count)[box]
        sx, sy = size[box, 0], size[box, 1]
        offset = torch.stack([within % sx, (within // sx) % sy, within // (sx * sy)], dim=1)
        cell, tri = lo[box] + offset, tri[box]
        centre = origin + (cell.double() + 0.5) * h
        maybe = bounds.lower(centre, tri) <= cell_reach * (1.0 + _CELL_SLACK) + bounds.slack
        cell, tri, centre = cell[maybe], tri[maybe], centre[maybe]
        _, sq = closest_point_on_triangles(centre, tris[tri], validate=False)
        keep = sq <= cell_reach**2 * (1.0 + _CELL_SLACK)
        return cell[keep], tri[keep]


def dense_wall_pairs(
    points: torch.Tensor,
    triangles: torch.Tensor,
    radius: float,
    *,
    max_pairs_per_chunk: int = 1 << 22,
) -> WallPairs:
    """The dense reference: every point against every triangle (BGNN's approach), ``O(P * F)``.

    Args:
        points: ``[P, 3]`` (m).
        triangles: ``[F, 3, 3]`` (m), same dtype as ``points``.
        radius: cut-off (m).
        max_pairs_per_chunk: bound on pairs evaluated at once (memory), not on the total.

    Returns:
        :class:`WallPairs` sorted by ``(point_idx, tri_idx)``.
    """
    check_tensor("points", points, (None, 3))
    check_tensor("triangles", triangles, (None, 3, 3))
    radius = _check_radius(radius)
    num_tris = triangles.shape[0]
    step = max(1, max_pairs_per_chunk // max(num_tris, 1))
    found = []
    for begin in range(0, points.shape[0], step):
        block = points[begin : begin + step]
        p_idx = torch.arange(block.shape[0], device=points.device).repeat_interleave(num_tris)
        t_idx = torch.arange(num_tris, device=points.device).repeat(block.shape[0])
        closest, sq = closest_point_on_triangles(block[p_idx], triangles[t_idx], validate=False)
        keep = sq < radius * radius
        found.append((p_idx[keep] + begin, t_idx[keep], closest[keep], sq[keep]))
    if not found:
        empty = points.new_zeros((0,), dtype=torch.int64)
        return WallPairs(empty, empty.clone(), points.new_zeros((0, 3)), points.new_zeros(0))
    return WallPairs(*(torch.cat(parts) for parts in zip(*found, strict=True)))
