"""Encoder -> processor -> decoder (GNS, Sanchez-Gonzalez et al. 2020)."""

from __future__ import annotations

from torch import Tensor, nn

from granular_pyg.errors import InputError
from granular_pyg.nn.mlp import MLP, _check_int
from granular_pyg.nn.processor import Processor, _check_graph

__all__ = ["EncodeProcessDecode"]


class EncodeProcessDecode(nn.Module):
    """Encode node and edge features to latents, process them, decode node outputs.

    - node encoder ``MLP(node_in -> latent)`` and edge encoder ``MLP(edge_in -> latent)``,
      both ending in a LayerNorm;
    - the ``processor`` (message passing on the latents);
    - decoder ``MLP(latent -> out_dim)`` without LayerNorm (the normalised acceleration).

    Works on any graph, including PyG batches (a ``Batch`` is a disjoint union: no message
    crosses between its graphs), isolated nodes and graphs with no edge at all.

    Args:
        node_in: node feature width.
        edge_in: edge feature width.
        out_dim: output width per node.
        processor: the processor; its ``latent`` must equal ``latent``.
        latent: latent width ``L``.
        mlp_layers: hidden layers of the encoder and decoder MLPs.

    Raises:
        InputError: ``processor.latent != latent`` or a non-positive width.
    """

    def __init__(
        self,
        node_in: int,
        edge_in: int,
        out_dim: int,
        processor: Processor,
        latent: int = 128,
        mlp_layers: int = 2,
    ) -> None:
        super().__init__()
        latent = _check_int("latent", latent, 1)
        if not isinstance(processor, Processor):
            raise InputError(f"processor: expected a Processor, got {type(processor).__name__}")
        if processor.latent != latent:
            raise InputError(
                f"processor: its latent width ({processor.latent}) differs from the model's "
                f"({latent}); set the processor's latent to the model's (the presets interpolate "
                "it as ${..latent})"
            )
        self.node_in = _check_int("node_in", node_in, 1)
        self.edge_in = _check_int("edge_in", edge_in, 1)
        self.out_dim = _check_int("out_dim", out_dim, 1)
        self.latent = latent
        self.node_encoder = MLP(self.node_in, latent, latent, mlp_layers, layer_norm=True)
        self.edge_encoder = MLP(self.edge_in, latent, latent, mlp_layers, layer_norm=True)
        self.processor = processor
        self.decoder = MLP(latent, latent, self.out_dim, mlp_layers, layer_norm=False)

    def forward(self, x: Tensor, edge_index: Tensor, edge_attr: Tensor) -> Tensor:
        """Predict one output per node.

        Args:
            x: ``[num_nodes, node_in]`` node features.
            edge_index: ``[2, num_edges]`` (source, target) node indices, int64.
            edge_attr: ``[num_edges, edge_in]`` edge features.

        Returns:
            ``[num_nodes, out_dim]``.

        Raises:
            InputError: wrong shapes or dtypes, or out-of-range node indices (values are not
                checked for NaN/Inf, for speed).
        """
        dtype = self.decoder[-1].weight.dtype
        _check_graph(x, edge_index, edge_attr, self.node_in, self.edge_in, dtype)
        # Under autocast the inference path keeps the edge latents in the autocast dtype.
        edge_latents = self.edge_encoder(edge_attr, store_in_autocast_dtype=True)
        latent_x, _ = self.processor(self.node_encoder(x), edge_index, edge_latents, overwrite=True)
        return self.decoder(latent_x)
