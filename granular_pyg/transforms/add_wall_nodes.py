"""Virtual wall nodes (the paper's boundary handling) as a PyG transform."""

from __future__ import annotations

import torch
from torch_geometric.data import Data
from torch_geometric.transforms import BaseTransform

from granular_pyg.errors import InputError
from granular_pyg.geometry import argmin_per_group, canonical_normals

__all__ = ["NORMAL_VARIANTS", "WALL_NODE_MODES", "AddWallNodes"]

#: The paper's normal variants: V1 none, V2 single (vertex order), V3 both (ordered by f_o).
NORMAL_VARIANTS = ("none", "single", "both")

#: Where wall nodes go: ``"triangle"``, one per (particle, triangle) within the cut-off (the
#: paper's); ``"patch"``, one per (particle, surface patch) at the patch's closest point, the
#: same whatever the triangles a flat or gently curved surface was cut into
#: (:func:`~granular_pyg.geometry.surface_patches`).
WALL_NODE_MODES = ("triangle", "patch")


class AddWallNodes(BaseTransform):
    r"""Add one virtual node per (particle, triangle) pair closer than ``radius`` (``per=
    "triangle"``), or per (particle, surface patch) pair at the patch's closest point (``per=
    "patch"``: the triangle of the patch nearest the particle, ties to the lower index).

    The node sits at the triangle's closest point to the particle (Eberly), at the walls' pose
    at ``data.time``, and sends one edge to its particle (wall -> particle only); with
    ``data.step_end`` the walls are those a step from ``data.time`` to it sees
    (:meth:`~granular_pyg.scenes.WallSet.contacts`). Node features
    by variant (``normal_feat``, 6 columns):

    - ``"none"`` (V1): six zeros;
    - ``"single"`` (V2): the normal from the triangle's vertex order, then three zeros;
    - ``"both"`` (V3): :func:`~granular_pyg.geometry.canonical_normals`, both orientations
      ordered by the paper's :math:`f_o` (smaller key first), identical for either winding.

    Expects ``data.pos [N, 3]`` (real particles, world frame, m), ``data.walls`` (a
    :class:`~granular_pyg.scenes.WallSet`), ``data.time`` (s) and optionally
    ``data.edge_index`` (particle edges). Appends the wall nodes after the ``N`` particles and
    sets:

    - ``pos [N + W, 3]``, ``edge_index`` (particle edges, then wall -> particle edges);
    - ``is_wall [N + W]`` bool, ``num_real = N``;
    - ``normal_feat [N + W, 6]`` (zeros for particles);
    - ``wall_vel [N + W, 3]`` the wall's velocity at the node (m/s; zeros for particles);
    - ``node_weight [N + W]``: 1 for particles; for a wall node, ``1 / k`` with ``k`` its
      particle's wall-node count when ``wall_weight`` (BGNN), else 1;
    - ``wall_tri [W]`` the triangle of each wall node (global index in the WallSet).

    No wall node is added when no triangle is within ``radius``.

    Args:
        radius: cut-off (m).
        normals: ``"none"``, ``"single"`` or ``"both"``.
        wall_weight: weight a particle's ``k`` wall nodes by ``1 / k``.
        per: ``"triangle"`` or ``"patch"`` (:data:`WALL_NODE_MODES`).
    """

    def __init__(
        self,
        radius: float,
        normals: str = "both",
        wall_weight: bool = False,
        per: str = "triangle",
    ) -> None:
        if per not in WALL_NODE_MODES:
            raise InputError(f"wall_nodes: expected one of {WALL_NODE_MODES}, got {per!r}")
        self.per = per
        if normals not in NORMAL_VARIANTS:
            raise InputError(f"normals: expected one of {NORMAL_VARIANTS}, got {normals!r}")
        if not radius > 0:
            raise InputError(f"radius: expected a positive cut-off in metres, got {radius!r}")
        self.radius = float(radius)
        self.normals = normals
        self.wall_weight = bool(wall_weight)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(radius={self.radius}, normals={self.normals})"

    def forward(self, data: Data) -> Data:
        pos = data.pos
        num_real = pos.shape[0]
        step_end = float(data.step_end) if "step_end" in data else None
        contacts = data.walls.contacts(pos, self.radius, float(data.time), step_end)
        if self.per == "patch" and contacts.point_idx.numel():
            contacts = self._nearest_per_patch(pos, contacts, data.walls)
        num_wall = contacts.point_idx.shape[0]
        if self.normals == "none":
            feat = pos.new_zeros((num_wall, 6))
        elif self.normals == "single":
            feat = torch.cat([contacts.normal, pos.new_zeros((num_wall, 3))], dim=1)
        else:
            feat = canonical_normals(contacts.normal)

        weight = pos.new_ones(num_wall)
        if self.wall_weight and num_wall:
            k = torch.bincount(contacts.point_idx, minlength=num_real).to(pos.dtype)
            weight = 1.0 / k[contacts.point_idx]

        wall_ids = torch.arange(num_real, num_real + num_wall, device=pos.device)
        wall_edges = torch.stack([wall_ids, contacts.point_idx.to(pos.device)])
        edge_index = data.edge_index if "edge_index" in data else wall_edges[:, :0]
        data.edge_index = torch.cat([edge_index, wall_edges], dim=1)
        data.pos = torch.cat([pos, contacts.closest])
        data.is_wall = torch.cat(
            [torch.zeros(num_real, dtype=torch.bool), torch.ones(num_wall, dtype=torch.bool)]
        )
        data.num_real = num_real
        data.normal_feat = torch.cat([pos.new_zeros((num_real, 6)), feat])
        data.wall_vel = torch.cat([pos.new_zeros((num_real, 3)), contacts.velocity])
        data.node_weight = torch.cat([pos.new_ones(num_real), weight])
        data.wall_tri = contacts.tri_idx
        return data

    @staticmethod
    def _nearest_per_patch(pos: torch.Tensor, contacts, walls):
        """Keep, of each (particle, patch) group of contacts, the one nearest the particle;
        the result stays sorted by particle, then patch."""
        patch = walls.patch_of.to(contacts.tri_idx.device)[contacts.tri_idx]
        group = contacts.point_idx * max(walls.num_patches, 1) + patch
        dist = torch.linalg.vector_norm(pos[contacts.point_idx] - contacts.closest, dim=1)
        _, rows = argmin_per_group(dist, group)
        return type(contacts)(*(col[rows] for col in contacts))
