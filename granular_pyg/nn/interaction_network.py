"""The interaction network: one GNS message-passing step with residual edge and node updates."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor
from torch_geometric.nn import MessagePassing

from granular_pyg.errors import InputError
from granular_pyg.nn.mlp import (
    MLP,
    _check_int,
    add,
    blocked_inference,
    fill_by_blocks,
    row_chunks,
    take_rows,
)

__all__ = ["AGGREGATIONS", "InteractionNetwork"]

#: Neighbourhood aggregations of :class:`InteractionNetwork`: GNS sums, BGNN averages.
AGGREGATIONS = ("sum", "mean")


class InteractionNetwork(MessagePassing):
    r"""One interaction-network step (Battaglia et al. 2016, as used by GNS and BGNN).

    For an edge :math:`j \to i` (``edge_index[0]`` is the source :math:`j`, ``edge_index[1]``
    the target :math:`i`, PyG's ``source_to_target`` flow):

    .. math::

        e'_{ij} = e_{ij} + \mathrm{MLP}_e([x_i, x_j, e_{ij}]), \qquad
        x'_i = x_i + \mathrm{MLP}_n\big([x_i, \textstyle\bigoplus_{j} e'_{ij}]\big)

    with :math:`\bigoplus` the sum (GNS) or the mean (BGNN) over the incoming edges of
    :math:`i`; a node without incoming edges aggregates to zero. Both MLPs end in a LayerNorm.

    The first layer of :math:`\mathrm{MLP}_e` is linear, so it is evaluated split into its three
    column blocks, :math:`W [x_i, x_j, e_{ij}] + b = (W_r x + b)_i + (W_s x)_j + W_e e_{ij}`:
    the two node terms are computed once per node and gathered per edge, which spares two
    thirds of that layer's per-edge multiplications (a node has tens of edges). The parameters
    are those of the plain ``edge_mlp`` (same ``state_dict``); the result equals
    ``edge_mlp(cat([x_i, x_j, e_ij]))`` up to float round-off.

    The updated edge latents :math:`e'` are returned and must be fed to the next step: a
    processor whose edge latents never change between steps is a known bug of a peer project.

    Args:
        latent: width ``L`` of the node and edge latents.
        aggr: ``"sum"`` or ``"mean"``.
        mlp_layers: hidden layers of each MLP.

    Raises:
        InputError: an unknown ``aggr`` or a non-positive width.
    """

    def __init__(self, latent: int, aggr: str = "sum", mlp_layers: int = 2) -> None:
        if aggr not in AGGREGATIONS:
            raise InputError(f"aggr: expected one of {AGGREGATIONS}, got {aggr!r}")
        super().__init__(aggr=aggr, flow="source_to_target")
        self.latent = _check_int("latent", latent, 1)
        self.edge_mlp = MLP(3 * self.latent, self.latent, self.latent, mlp_layers, layer_norm=True)
        self.node_mlp = MLP(2 * self.latent, self.latent, self.latent, mlp_layers, layer_norm=True)

    def forward(
        self, x: Tensor, edge_index: Tensor, edge_attr: Tensor, overwrite: bool = False
    ) -> tuple[Tensor, Tensor]:
        """Run one step.

        Shapes are not checked here (see :class:`~granular_pyg.nn.Processor`).

        Args:
            x: ``[num_nodes, latent]`` node latents.
            edge_index: ``[2, num_edges]`` (source, target) node indices, int64.
            edge_attr: ``[num_edges, latent]`` edge latents.
            overwrite: the caller no longer needs ``edge_attr``: on the blocked inference path
                the updated latents are written into it (one ``[E, L]`` buffer, not two).

        Returns:
            ``(x_new [num_nodes, latent], edge_attr_new [num_edges, latent])``.
        """
        num_nodes = x.size(0)
        edge_attr = self.update_edges(x, edge_index, edge_attr, overwrite)
        messages = self.edge_messages(edge_index, edge_attr, num_nodes)
        if blocked_inference(messages.shape[0]):
            aggregated = self.aggregate_blocked(messages, edge_index[1], num_nodes)
        else:
            aggregated = self.propagate(edge_index, m=messages, size=(num_nodes, num_nodes))
        return self.update_nodes(x, aggregated), edge_attr

    def aggregate_blocked(self, messages: Tensor, target: Tensor, num_nodes: int) -> Tensor:
        """The sum or mean of the messages per target node, accumulated block by block in
        float32 (whatever the messages' storage dtype): ``[num_nodes, latent]``. The inference
        path's twin of ``propagate``, equal to it up to float round-off.

        Args:
            messages: ``[num_edges, latent]`` (float32 or bfloat16).
            target: ``[num_edges]`` target node of each edge.
            num_nodes: number of nodes.
        """
        acc_dtype = torch.promote_types(messages.dtype, torch.float32)
        out = messages.new_zeros((num_nodes, messages.shape[1]), dtype=acc_dtype)
        for rows in row_chunks(messages.shape[0]):
            out.index_add_(0, target[rows], messages[rows].to(acc_dtype))
        if self.aggr == "mean":
            count = torch.bincount(target, minlength=num_nodes).clamp_(min=1)
            out /= count.unsqueeze(1).to(acc_dtype)
        return out

    def update_nodes(self, x: Tensor, aggregated: Tensor) -> Tensor:
        """Residual node update ``x'_i = x_i + MLP_n([x_i, a_i])``: ``[num_nodes, latent]``.

        The first Linear layer of ``node_mlp`` runs split into its two column blocks
        (``W_x x + W_a a + b``), so the ``[num_nodes, 2 latent]`` concatenation is never built;
        without autograd the nodes run in cache-sized blocks. Equal to the concatenated form up
        to float round-off.

        Args:
            x: ``[num_nodes, latent]`` node latents.
            aggregated: ``[num_nodes, latent]`` aggregated edge messages.
        """
        first, latent = self.node_mlp[0], self.latent
        own_weight = first.weight[:, :latent]
        message_weight = first.weight[:, latent:].t()

        def block(rows: slice | None) -> Tensor:
            own = take_rows(x, rows)
            hidden = torch.addmm(
                F.linear(own, own_weight, first.bias), take_rows(aggregated, rows), message_weight
            )
            return own + self.node_mlp.run_block(hidden, start=1)

        if not blocked_inference(x.shape[0]):
            return block(None)
        return fill_by_blocks(torch.empty_like(x), block)

    def update_edges(
        self, x: Tensor, edge_index: Tensor, edge_attr: Tensor, overwrite: bool = False
    ) -> Tensor:
        """Residual edge update ``e'_ij = e_ij + MLP_e([x_i, x_j, e_ij])``: ``[num_edges, latent]``.

        The first Linear layer of ``edge_mlp`` runs split into its column blocks: the ``x_i``
        and ``x_j`` terms (and the bias) once per node, gathered per edge. Without autograd
        (rollouts) the edges run in cache-sized blocks (:func:`~granular_pyg.nn.mlp.row_chunks`):
        the same numbers, but memory traffic and peak memory of one block's hidden layers. A
        block reads only its own rows of ``e``, so with ``overwrite`` the result goes into
        ``edge_attr`` itself.

        Args:
            x: ``[num_nodes, latent]`` node latents.
            edge_index: ``[2, num_edges]`` (source ``j``, target ``i``) node indices.
            edge_attr: ``[num_edges, latent]`` edge latents ``e``.
            overwrite: write the result into ``edge_attr`` (blocked inference path only).
        """
        first, latent = self.edge_mlp[0], self.latent
        weight = first.weight  # [out, 3 L]: column blocks for x_i, x_j, e_ij
        target = F.linear(x, weight[:, :latent], first.bias)  # [num_nodes, out]
        source = F.linear(x, weight[:, latent : 2 * latent])  # [num_nodes, out]
        edge_weight = weight[:, 2 * latent :].t()

        def block(rows: slice | None) -> Tensor:
            edges = take_rows(edge_index, rows, dim=1)
            latents = take_rows(edge_attr, rows)
            hidden = add(target.index_select(0, edges[1]), source.index_select(0, edges[0]))
            hidden = torch.addmm(hidden, latents, edge_weight)
            return latents + self.edge_mlp.run_block(hidden, start=1)

        if not blocked_inference(edge_attr.shape[0]):
            return block(None)
        return fill_by_blocks(edge_attr if overwrite else torch.empty_like(edge_attr), block)

    def edge_messages(self, edge_index: Tensor, edge_attr: Tensor, num_nodes: int) -> Tensor:
        """What each edge sends to its target before aggregation: here ``e'_ij`` itself.

        Args:
            edge_index: ``[2, num_edges]``.
            edge_attr: ``[num_edges, latent]`` updated edge latents ``e'``.
            num_nodes: number of nodes.

        Returns:
            ``[num_edges, latent]``.
        """
        del edge_index, num_nodes  # used by subclasses that weight the messages
        return edge_attr

    def message(self, m: Tensor) -> Tensor:
        """Pass the per-edge messages through to the aggregation."""
        return m

    def __repr__(self) -> str:
        return f"{self.__class__.__name__}({self.latent}, aggr={self.aggr!r})"
