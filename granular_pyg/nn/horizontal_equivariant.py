r"""A network equivariant by construction to rotations about gravity and to vertical mirrors.

Gravity fixes only the vertical: turning a scene about the z axis, or mirroring it through a
vertical plane, must turn or mirror its accelerations and change nothing else. The group is
O(2) acting on the horizontal plane, z untouched. This network is exactly equivariant to it
(to round-off) because every quantity it holds is either

- a **scalar**, invariant under O(2): vertical components, dot products of horizontal vectors,
  lengths; or
- a **horizontal vector** ``[..., 2]``, transformed by the O(2) element: horizontal velocities,
  the horizontal edge displacement ``d_h``, wall-normal directions,

and it only ever combines them in equivariant ways (PaiNN / EGNN style, restricted to the
plane): scalars from dot products of vectors, vectors as sums of vectors times scalars, linear
mixes of vector channels without bias. No cross product (a pseudoscalar) appears, so mirrors
are covered as well as rotations.

Node ``i`` holds scalars ``s_i [L]`` and ``C`` horizontal vector channels ``V_i [C, 2]``; edge
``j -> i`` holds scalars ``e_ij [L]`` and its horizontal displacement ``d_ij [2]`` (over the
cut-off). One layer:

.. math::

    p^{(i)}_{ij} = V_i \cdot d_{ij}, \quad p^{(j)}_{ij} = V_j \cdot d_{ij}, \qquad
    e'_{ij} = e_{ij} + \mathrm{MLP}_e([s_i, s_j, e_{ij}, p^{(i)}_{ij}, p^{(j)}_{ij}])

    \Delta V_i = \bigoplus_j \big( a(e'_{ij}) \odot V_j + b(e'_{ij}) \otimes d_{ij} \big), \qquad
    s'_i = s_i + \mathrm{MLP}_n([s_i, \textstyle\bigoplus_j e'_{ij}, |V_i + \Delta V_i|^2])

    V'_i = V_i + W (\Delta V_i) \odot \sigma(g(s'_i))

with :math:`\bigoplus` the mean (or sum) over incoming edges, ``a, b, g`` linear maps to ``C``
gates and ``W`` a ``C x C`` channel mix. The decoder gives the vertical acceleration from the
scalars and the horizontal one as ``sum_c w_c(s_i) V_{i,c}``.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch_geometric.utils import scatter

from granular_pyg.errors import InputError
from granular_pyg.nn.mlp import MLP, _check_int

__all__ = [
    "HorizontalEquivariantLayer",
    "HorizontalEquivariantNetwork",
    "HorizontalEquivariantProcessor",
]

AGGREGATIONS = ("sum", "mean")


def _horizontal_dot(vectors: Tensor, direction: Tensor) -> Tensor:
    """``[E, C]`` dot products of ``vectors [E, C, 2]`` with ``direction [E, 2]``."""
    return (vectors * direction.unsqueeze(1)).sum(dim=-1)


class HorizontalEquivariantLayer(nn.Module):
    """One message-passing step over scalars and horizontal vector channels (see the module).

    Args:
        latent: scalar width ``L`` of nodes and edges.
        channels: vector channels ``C``.
        aggr: ``"mean"`` or ``"sum"``.
        mlp_layers: hidden layers of each MLP.
        wall_sum: the node update also gets the sum of the edge scalars from wall nodes.
    """

    def __init__(
        self,
        latent: int,
        channels: int,
        aggr: str = "mean",
        mlp_layers: int = 2,
        wall_sum: bool = False,
    ) -> None:
        super().__init__()
        if aggr not in AGGREGATIONS:
            raise InputError(f"aggr: expected one of {AGGREGATIONS}, got {aggr!r}")
        self.latent, self.channels, self.aggr = latent, channels, aggr
        self.wall_sum = wall_sum
        node_in = (3 if wall_sum else 2) * latent + channels
        self.edge_mlp = MLP(3 * latent + 2 * channels, latent, latent, mlp_layers, layer_norm=True)
        self.node_mlp = MLP(node_in, latent, latent, mlp_layers, layer_norm=True)
        self.vector_gates = nn.Linear(latent, 2 * channels)
        self.channel_mix = nn.Linear(channels, channels, bias=False)
        self.update_gate = nn.Linear(latent, channels)

    def forward(
        self,
        s: Tensor,
        vec: Tensor,
        edge_index: Tensor,
        e: Tensor,
        d: Tensor,
        from_wall: Tensor | None = None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """One step.

        Args:
            s: ``[N, L]`` node scalars.
            vec: ``[N, C, 2]`` node horizontal vectors.
            edge_index: ``[2, E]`` (source ``j``, target ``i``).
            e: ``[E, L]`` edge scalars.
            d: ``[E, 2]`` horizontal displacement ``x_i - x_j`` over the cut-off.
            from_wall: ``[E]`` bool, the edge comes from a wall node (needed with
                ``wall_sum``).

        Returns:
            ``(s' [N, L], vec' [N, C, 2], e' [E, L])``.
        """
        src, dst = edge_index
        num = s.shape[0]
        v_src, v_dst = vec[src], vec[dst]
        e_in = torch.cat(
            [s[dst], s[src], e, _horizontal_dot(v_dst, d), _horizontal_dot(v_src, d)], 1
        )
        e = e + self.edge_mlp(e_in)
        a, b = self.vector_gates(e).chunk(2, dim=1)  # [E, C] each
        msg = a.unsqueeze(-1) * v_src + b.unsqueeze(-1) * d.unsqueeze(1)  # [E, C, 2]
        agg_vec = scatter(msg, dst, dim=0, dim_size=num, reduce=self.aggr)
        agg_s = scatter(e, dst, dim=0, dim_size=num, reduce=self.aggr)
        norms = (vec + agg_vec).square().sum(dim=-1)  # [N, C], invariant
        node_in = [s, agg_s, norms]
        if self.wall_sum:  # a wall's support is not averaged away among the particles'
            walls = e * from_wall.unsqueeze(1).to(e.dtype)
            node_in.append(scatter(walls, dst, dim=0, dim_size=num, reduce="sum"))
        s = s + self.node_mlp(torch.cat(node_in, dim=1))
        mixed = self.channel_mix(agg_vec.transpose(1, 2)).transpose(1, 2)  # [N, C, 2]
        vec = vec + mixed * torch.sigmoid(self.update_gate(s)).unsqueeze(-1)
        return s, vec, e


class HorizontalEquivariantProcessor(nn.Module):
    """The zoo's equivariant processor: ``num_steps`` unshared
    :class:`HorizontalEquivariantLayer` steps (``model/processor=equivariant``). A
    :class:`~granular_pyg.simulator.LearnedSimulator` given this processor builds the scalar
    and vector inputs it needs and a :class:`HorizontalEquivariantNetwork` around it.

    Args:
        latent: scalar width ``L``.
        num_steps: message-passing steps.
        channels: horizontal vector channels ``C``.
        aggr: ``"mean"`` or ``"sum"``.
        mlp_layers: hidden layers of each MLP.
        wall_sum: each step's node update also gets the **sum** of the messages from wall
            nodes, beside the aggregate over all edges. Under ``mean`` a lid under a bed is one
            or two of some twenty messages, and its removal moved a trained model's
            acceleration of the bottom layer by 0.01 m/s^2 (LIGGGHTS: 5-9 m/s^2); summed, the
            support of each surface a particle touches counts whole. With ``wall_nodes:
            patch`` (a node per surface) the sum does not depend on the triangulation.
    """

    def __init__(
        self,
        latent: int,
        num_steps: int = 3,
        channels: int = 16,
        aggr: str = "mean",
        mlp_layers: int = 2,
        wall_sum: bool = False,
    ) -> None:
        super().__init__()
        self.latent = _check_int("latent", latent, 1)
        self.num_steps = _check_int("num_steps", num_steps, 1)
        self.channels = _check_int("channels", channels, 1)
        if not isinstance(wall_sum, bool):
            raise InputError(f"wall_sum: expected true or false, got {wall_sum!r}")
        self.wall_sum = wall_sum
        self.layers = nn.ModuleList(
            HorizontalEquivariantLayer(self.latent, self.channels, aggr, mlp_layers, wall_sum)
            for _ in range(self.num_steps)
        )

    def forward(
        self,
        s: Tensor,
        vec: Tensor,
        edge_index: Tensor,
        e: Tensor,
        d: Tensor,
        from_wall: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Run every step; returns the node scalars ``[N, L]`` and vectors ``[N, C, 2]``
        (``from_wall [E]``: the edges from wall nodes, needed with ``wall_sum``)."""
        if self.wall_sum and from_wall is None:
            raise InputError("wall_sum: the processor needs from_wall, the edges from walls")
        for layer in self.layers:
            s, vec, e = layer(s, vec, edge_index, e, d, from_wall)
        return s, vec

    def extra_repr(self) -> str:
        return f"num_steps={self.num_steps}, channels={self.channels}, wall_sum={self.wall_sum}"


class HorizontalEquivariantNetwork(nn.Module):
    """Encoder, :class:`HorizontalEquivariantProcessor`, decoder; output ``[N, 3]`` with the
    horizontal acceleration in columns 0-1 and the vertical in column 2.

    Args:
        node_in: node scalar inputs.
        vec_in: node horizontal vector inputs (channels).
        edge_in: edge scalar inputs.
        processor: the processor; its ``latent`` is the network's.
        mlp_layers: hidden layers of the encoder and decoder MLPs.
    """

    def __init__(
        self,
        node_in: int,
        vec_in: int,
        edge_in: int,
        processor: HorizontalEquivariantProcessor,
        mlp_layers: int = 2,
    ) -> None:
        super().__init__()
        latent, channels = processor.latent, processor.channels
        self.node_in, self.vec_in, self.edge_in = node_in, vec_in, edge_in
        self.node_encoder = MLP(node_in, latent, latent, mlp_layers, layer_norm=True)
        self.vec_encoder = nn.Linear(vec_in, channels, bias=False)
        self.edge_encoder = MLP(edge_in, latent, latent, mlp_layers, layer_norm=True)
        self.processor = processor
        self.decoder = MLP(latent, latent, 1 + channels, mlp_layers, layer_norm=False)

    def forward(
        self,
        x: Tensor,
        vec: Tensor,
        edge_index: Tensor,
        edge_attr: Tensor,
        edge_vec: Tensor,
        from_wall: Tensor | None = None,
    ) -> Tensor:
        """Predict the normalised acceleration of every node.

        Args:
            x: ``[N, node_in]`` node scalars.
            vec: ``[N, vec_in, 2]`` node horizontal vectors.
            edge_index: ``[2, E]`` int64 (source, target).
            edge_attr: ``[E, edge_in]`` edge scalars.
            edge_vec: ``[E, 2]`` horizontal edge displacement over the cut-off.
            from_wall: ``[E]`` bool, the edges from wall nodes (the processor's ``wall_sum``).

        Returns:
            ``[N, 3]``: ``(a_x, a_y, a_z)``.
        """
        s = self.node_encoder(x)
        v = self.vec_encoder(vec.transpose(1, 2)).transpose(1, 2)
        e = self.edge_encoder(edge_attr)
        s, v = self.processor(s, v, edge_index, e, edge_vec.to(s.dtype), from_wall)
        out = self.decoder(s)
        horizontal = (out[:, 1:].unsqueeze(-1) * v.to(out.dtype)).sum(dim=1)  # [N, 2]
        return torch.cat([horizontal, out[:, :1]], dim=1)
