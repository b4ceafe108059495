"""Edge-aware GATv2-style attention in place of the interaction network's sum or mean."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn
from torch_geometric.utils import softmax

from granular_pyg.errors import InputError
from granular_pyg.nn.interaction_network import InteractionNetwork
from granular_pyg.nn.mlp import _check_int

__all__ = ["AttentionInteractionNetwork"]


class AttentionInteractionNetwork(InteractionNetwork):
    r"""Interaction network whose aggregation is learned, normalised attention.

    The edge update is the interaction network's, :math:`e'_{ij} = e_{ij} +
    \mathrm{MLP}_e([x_i, x_j, e_{ij}])`. Each of ``H`` heads then scores every incoming edge
    of node :math:`i` and normalises the scores over those edges (GATv2, Brody et al., ICLR
    2022: the score is a linear map *after* the nonlinearity, and it is "dynamic" because
    :math:`e'_{ij}` already mixes :math:`x_i` and :math:`x_j`):

    .. math::

        \alpha^h_{ij} = \operatorname{softmax}_{j \in \mathcal{N}(i)}
            \big(a_h^\top \mathrm{LeakyReLU}(e'_{ij})\big), \qquad
        m_i = \big\Vert_{h=1}^{H} \sum_{j \in \mathcal{N}(i)} \alpha^h_{ij}\, V_h e'_{ij},
        \qquad x'_i = x_i + \mathrm{MLP}_n([x_i, m_i])

    where :math:`V_h e'` is head :math:`h`'s slice (``L / H`` values) of one linear map ``V``,
    and the heads are concatenated back to ``L``. A node with no incoming edge gets
    :math:`m_i = 0`.

    Why it suits particles near walls: a particle near a wall receives ``k`` wall-node
    messages, one per nearby triangle, and ``k`` depends on how finely the mesh is
    tessellated, not on the physics. With sum aggregation the wall's contribution scales with
    ``k`` (a tessellation artefact: split a triangle in two and the wall pushes twice as hard);
    BGNN's fix is a hand-set ``1/k`` weight on the wall nodes' features. Attention normalises
    over the neighbours by construction and lets the model itself weigh wall nodes against
    particles, and near neighbours against far ones.

    Args:
        latent: width ``L`` of the node and edge latents; must be divisible by ``heads``.
        aggr: only ``"sum"`` (the attention-weighted sum; the weights already normalise).
            Accepted so every processor layer takes the same arguments.
        mlp_layers: hidden layers of each MLP.
        heads: number of attention heads ``H``.

    Raises:
        InputError: ``latent % heads != 0``, ``aggr`` other than ``"sum"``, or a non-positive
            width.
    """

    negative_slope = 0.2  # of the LeakyReLU before the scores, as in GATv2

    def __init__(self, latent: int, aggr: str = "sum", mlp_layers: int = 2, heads: int = 4) -> None:
        latent = _check_int("latent", latent, 1)
        heads = _check_int("heads", heads, 1)
        if latent % heads:
            raise InputError(
                f"heads: latent ({latent}) must be divisible by heads ({heads}); "
                "choose heads among the divisors of latent"
            )
        if aggr != "sum":
            raise InputError(
                f"aggr: attention aggregates by an attention-weighted sum, expected 'sum', "
                f"got {aggr!r}; leave aggr unset for the attention layer"
            )
        super().__init__(latent, aggr="sum", mlp_layers=mlp_layers)
        self.heads = heads
        self.score = nn.Linear(latent, heads, bias=False)  # a bias would cancel in the softmax
        self.value = nn.Linear(latent, latent)

    def edge_messages(self, edge_index: Tensor, edge_attr: Tensor, num_nodes: int) -> Tensor:
        """Attention-weighted values ``alpha^h_ij V_h e'_ij``, heads concatenated.

        Args:
            edge_index: ``[2, num_edges]``.
            edge_attr: ``[num_edges, latent]`` updated edge latents ``e'``.
            num_nodes: number of nodes.

        Returns:
            ``[num_edges, latent]``; summing them per target gives ``m_i``.
        """
        alpha = self.attention_weights(edge_index, edge_attr, num_nodes)  # [E, H]
        value = self.value(edge_attr).view(-1, self.heads, self.latent // self.heads)
        return (alpha.unsqueeze(-1) * value).reshape(-1, self.latent)

    def attention_weights(self, edge_index: Tensor, edge_attr: Tensor, num_nodes: int) -> Tensor:
        """Attention weights ``alpha [num_edges, heads]``; they sum to 1 over each target's edges.

        Args:
            edge_index: ``[2, num_edges]``.
            edge_attr: ``[num_edges, latent]`` updated edge latents ``e'``.
            num_nodes: number of nodes.
        """
        scores = self.score(F.leaky_relu(edge_attr, self.negative_slope))
        return softmax(scores, edge_index[1], num_nodes=num_nodes)

    def __repr__(self) -> str:
        return f"{self.__class__.__name__}({self.latent}, heads={self.heads})"
