"""The interaction network: one GNS message-passing step with residual edge and node updates."""

from __future__ import annotations

import torch
from torch import Tensor
from torch_geometric.nn import MessagePassing

from granular_pyg.errors import InputError
from granular_pyg.nn.mlp import MLP, _check_int

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

    def forward(self, x: Tensor, edge_index: Tensor, edge_attr: Tensor) -> tuple[Tensor, Tensor]:
        """Run one step.

        Shapes are not checked here (see :class:`~granular_pyg.nn.Processor`).

        Args:
            x: ``[num_nodes, latent]`` node latents.
            edge_index: ``[2, num_edges]`` (source, target) node indices, int64.
            edge_attr: ``[num_edges, latent]`` edge latents.

        Returns:
            ``(x_new [num_nodes, latent], edge_attr_new [num_edges, latent])``.
        """
        num_nodes = x.size(0)
        edge_attr = self.edge_updater(edge_index, x=x, edge_attr=edge_attr)
        messages = self.edge_messages(edge_index, edge_attr, num_nodes)
        aggregated = self.propagate(edge_index, m=messages, size=(num_nodes, num_nodes))
        x = x + self.node_mlp(torch.cat([x, aggregated], dim=-1))
        return x, edge_attr

    def edge_update(self, x_i: Tensor, x_j: Tensor, edge_attr: Tensor) -> Tensor:
        """Residual edge update ``e'_ij``: ``[num_edges, latent]``."""
        return edge_attr + self.edge_mlp(torch.cat([x_i, x_j, edge_attr], dim=-1))

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
