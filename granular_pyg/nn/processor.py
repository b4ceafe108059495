"""The processor: a stack of unshared message-passing layers (the zoo's common trunk)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from granular_pyg.errors import InputError, check_tensor
from granular_pyg.nn.attention_interaction_network import AttentionInteractionNetwork
from granular_pyg.nn.interaction_network import InteractionNetwork
from granular_pyg.nn.mlp import _check_int

__all__ = ["PROCESSOR_LAYERS", "Processor"]

#: Layer kinds of :class:`Processor` by name (``layer`` argument and the Hydra presets).
PROCESSOR_LAYERS: dict[str, type[InteractionNetwork]] = {
    "interaction": InteractionNetwork,
    "attention": AttentionInteractionNetwork,
}


@torch.compiler.disable  # data-dependent checks: run eagerly, outside a compiled graph
def _check_graph(
    x: Tensor,
    edge_index: Tensor,
    edge_attr: Tensor,
    node_dim: int,
    edge_dim: int,
    dtype: torch.dtype,
) -> None:
    """Check ``x [N, node_dim]``, ``edge_index [2, E]`` (int64) and ``edge_attr [E, edge_dim]``.

    Shapes, dtypes (``x`` and ``edge_attr`` in the parameters' ``dtype``, any floating dtype
    under autocast, which mixes them) and index ranges only: the NaN/Inf check is off for speed.

    Raises:
        InputError: naming the offending argument.
    """
    check_tensor("x", x, (None, node_dim), floating=False, finite=False)
    check_tensor("edge_index", edge_index, (2, None), floating=False)
    check_tensor(
        "edge_attr", edge_attr, (edge_index.size(1), edge_dim), floating=False, finite=False
    )
    mixed = torch.is_autocast_enabled(x.device.type)
    if not mixed and (x.dtype != dtype or edge_attr.dtype != dtype):
        raise InputError(
            f"x/edge_attr: expected {dtype} like the model's parameters, got "
            f"{x.dtype}/{edge_attr.dtype}; convert the inputs or the model with .to()"
        )
    if edge_index.dtype != torch.long:
        raise InputError(
            f"edge_index: expected int64 node indices, got {edge_index.dtype}; convert with .long()"
        )
    if edge_index.numel():
        low, high = (int(v) for v in torch.aminmax(edge_index))
        if low < 0 or high >= x.size(0):
            raise InputError(
                f"edge_index: node indices must lie in [0, {x.size(0) - 1}] "
                f"(num_nodes = {x.size(0)}), got range [{low}, {high}]"
            )


class Processor(nn.Module):
    """``num_steps`` message-passing layers with unshared weights, run in sequence.

    Each layer takes and returns ``(x, edge_attr)``, so the edge latents updated by one step are
    the input of the next. Presets in ``conf/model/processor/``: ``gns`` (10 interaction steps,
    sum), ``bgnn`` (3 interaction steps, mean), ``attention`` (3 attention steps, 4 heads).

    Args:
        latent: width ``L`` of the node and edge latents.
        num_steps: number of message-passing steps (one layer each, weights not shared).
        layer: ``"interaction"`` (:class:`~granular_pyg.nn.InteractionNetwork`) or
            ``"attention"`` (:class:`~granular_pyg.nn.AttentionInteractionNetwork`).
        aggr: neighbourhood aggregation, ``"sum"`` or ``"mean"`` (attention: ``"sum"`` only).
        mlp_layers: hidden layers of each MLP.
        heads: attention heads (``"attention"`` only; ignored otherwise).

    Raises:
        InputError: an unknown ``layer`` or ``aggr``, ``num_steps < 1``, or ``latent % heads``
            not zero for attention.
    """

    def __init__(
        self,
        latent: int,
        num_steps: int,
        layer: str = "interaction",
        aggr: str = "sum",
        mlp_layers: int = 2,
        heads: int = 4,
    ) -> None:
        super().__init__()
        if layer not in PROCESSOR_LAYERS:
            raise InputError(f"layer: expected one of {sorted(PROCESSOR_LAYERS)}, got {layer!r}")
        self.latent = _check_int("latent", latent, 1)
        self.num_steps = _check_int("num_steps", num_steps, 1)
        self.layer = layer
        self.aggr = aggr
        extra = {"heads": heads} if layer == "attention" else {}
        self.layers = nn.ModuleList(
            PROCESSOR_LAYERS[layer](self.latent, aggr=aggr, mlp_layers=mlp_layers, **extra)
            for _ in range(self.num_steps)
        )

    def forward(
        self, x: Tensor, edge_index: Tensor, edge_attr: Tensor, overwrite: bool = False
    ) -> tuple[Tensor, Tensor]:
        """Run every step.

        Args:
            x: ``[num_nodes, latent]`` node latents.
            edge_index: ``[2, num_edges]`` (source, target) node indices, int64.
            edge_attr: ``[num_edges, latent]`` edge latents.
            overwrite: the caller no longer needs ``edge_attr`` (inference may reuse it).

        Returns:
            ``(x [num_nodes, latent], edge_attr [num_edges, latent])`` after the last step.

        Raises:
            InputError: wrong shapes or dtypes, or out-of-range node indices.
        """
        dtype = self.layers[0].node_mlp[0].weight.dtype
        _check_graph(x, edge_index, edge_attr, self.latent, self.latent, dtype)
        for i, layer in enumerate(self.layers):
            # after the first step the edge latents are this loop's own
            x, edge_attr = layer(x, edge_index, edge_attr, overwrite=overwrite or i > 0)
        return x, edge_attr

    def extra_repr(self) -> str:
        return f"layer={self.layer!r}, num_steps={self.num_steps}, aggr={self.aggr!r}"
