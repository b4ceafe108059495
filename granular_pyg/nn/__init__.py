"""The network zoo: MLP, message-passing layers, processor, encode-process-decode."""

from granular_pyg.nn.attention_interaction_network import AttentionInteractionNetwork
from granular_pyg.nn.encode_process_decode import EncodeProcessDecode
from granular_pyg.nn.horizontal_equivariant import (
    HorizontalEquivariantNetwork,
    HorizontalEquivariantProcessor,
)
from granular_pyg.nn.interaction_network import AGGREGATIONS, InteractionNetwork
from granular_pyg.nn.mlp import MLP
from granular_pyg.nn.processor import PROCESSOR_LAYERS, Processor

__all__ = [
    "AGGREGATIONS",
    "MLP",
    "PROCESSOR_LAYERS",
    "AttentionInteractionNetwork",
    "EncodeProcessDecode",
    "HorizontalEquivariantNetwork",
    "HorizontalEquivariantProcessor",
    "InteractionNetwork",
    "Processor",
]
