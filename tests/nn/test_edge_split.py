"""The interaction network's split edge MLP equals the plain concatenated computation.

``InteractionNetwork`` evaluates the first Linear layer of its edge MLP per node for the ``x_i``
and ``x_j`` blocks and gathers the results per edge. Here a brute-force reference runs the same
parameters the plain way, ``edge_mlp(cat([x_i, x_j, e_ij]))`` with an explicit per-target sum or
mean, and both must agree to round-off in the outputs and in every gradient.
"""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from granular_pyg.nn import AttentionInteractionNetwork, InteractionNetwork, Processor

LATENT = 16

#: (layer class, aggr) of every message-passing layer of the zoo.
LAYERS = [
    (InteractionNetwork, "sum"),
    (InteractionNetwork, "mean"),
    (AttentionInteractionNetwork, "sum"),
]
LAYER_IDS = ["sum", "mean", "attention"]

#: Relative tolerance of the comparisons per dtype (round-off of a different summation order).
RTOL = {torch.float32: 4e-6, torch.float64: 1e-12}  # float32: about 32 ulps

#: (num_nodes, num_edges, nodes that have edges): a dense graph, one with many nodes without
#: any edge, and one with no edge at all.
GRAPHS = [(12, 200, 12), (30, 60, 10), (7, 0, 0)]
GRAPH_IDS = ["dense", "isolated-nodes", "no-edges"]


def plain_mlp(mlp: torch.nn.Sequential, h: Tensor) -> Tensor:
    """The MLP's layers one after the other, ReLU out of place (``MLP`` runs it in place)."""
    return torch.nn.Sequential.forward(mlp, h)


def plain_layer(layer: InteractionNetwork, x: Tensor, edge_index: Tensor, edge_attr: Tensor):
    """The layer computed the plain way: concatenated edge-MLP input, explicit aggregation,
    out-of-place ReLU."""
    num_nodes = x.size(0)
    source, target = edge_index
    edge_in = torch.cat([x[target], x[source], edge_attr], dim=-1)  # [x_i, x_j, e_ij]
    edge_new = edge_attr + plain_mlp(layer.edge_mlp, edge_in)
    messages = layer.edge_messages(edge_index, edge_new, num_nodes)
    aggregated = torch.zeros_like(x).index_add(0, target, messages)
    if layer.aggr == "mean":
        ones = torch.ones(target.numel(), dtype=x.dtype)
        count = torch.zeros(num_nodes, dtype=x.dtype).index_add(0, target, ones)
        aggregated = aggregated / count.clamp(min=1).unsqueeze(-1)
    x_new = x + plain_mlp(layer.node_mlp, torch.cat([x, aggregated], dim=-1))
    return x_new, edge_new


def graph(num_nodes: int, num_edges: int, with_edges: int, dtype: torch.dtype, seed: int = 0):
    """``x``, ``edge_index``, ``edge_attr``; only the first ``with_edges`` nodes have edges."""
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(num_nodes, LATENT, generator=gen, dtype=dtype)
    edge_index = torch.randint(0, max(with_edges, 1), (2, num_edges), generator=gen)
    edge_attr = torch.randn(num_edges, LATENT, generator=gen, dtype=dtype)
    return x, edge_index, edge_attr


def assert_close(actual: Tensor, expected: Tensor, rtol: float) -> None:
    """``max |actual - expected| <= rtol * max |expected|`` (relative to the tensor's scale)."""
    assert actual.shape == expected.shape
    assert actual.dtype == expected.dtype
    if expected.numel() == 0:
        return
    scale = expected.abs().max().clamp(min=torch.finfo(expected.dtype).tiny)
    error = (actual - expected).abs().max()
    assert error <= rtol * scale, f"max error {float(error):.3g} > {rtol:g} x {float(scale):.3g}"


def make_layer(cls: type[InteractionNetwork], aggr: str, mlp_layers: int, dtype: torch.dtype):
    torch.manual_seed(1)
    layer = cls(LATENT, aggr=aggr, mlp_layers=mlp_layers).to(dtype)
    # LayerNorm starts at weight 1, bias 0: perturb it so that every parameter matters.
    with torch.no_grad():
        for parameter in layer.parameters():
            parameter.add_(0.1 * torch.randn_like(parameter))
    return layer


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("shape", GRAPHS, ids=GRAPH_IDS)
@pytest.mark.parametrize("mlp_layers", [0, 2])
@pytest.mark.parametrize(("cls", "aggr"), LAYERS, ids=LAYER_IDS)
def test_split_edge_mlp_equals_the_concatenated_one_with_its_gradients(
    cls, aggr, mlp_layers, shape, dtype
):
    layer = make_layer(cls, aggr, mlp_layers, dtype)
    x, edge_index, edge_attr = graph(*shape, dtype=dtype)
    rtol = RTOL[dtype]

    outputs, grads = [], []
    for run in (layer, lambda *args: plain_layer(layer, *args)):
        layer.zero_grad()
        x_in = x.clone().requires_grad_()
        edge_in = edge_attr.clone().requires_grad_()
        x_out, edge_out = run(x_in, edge_index, edge_in)
        # a loss that weighs every output differently, so that no gradient is trivially equal
        gen = torch.Generator().manual_seed(2)
        loss = (x_out * torch.randn(x_out.shape, generator=gen, dtype=dtype)).sum() + (
            edge_out * torch.randn(edge_out.shape, generator=gen, dtype=dtype)
        ).sum()
        loss.backward()
        outputs.append((x_out.detach(), edge_out.detach()))
        grads.append(
            [x_in.grad, edge_in.grad]
            + [p.grad if p.grad is not None else torch.zeros_like(p) for p in layer.parameters()]
        )

    (x_split, edge_split), (x_plain, edge_plain) = outputs
    assert_close(x_split, x_plain, rtol)
    assert_close(edge_split, edge_plain, rtol)
    names = ["x", "edge_attr"] + [name for name, _ in layer.named_parameters()]
    for name, split, plain in zip(names, *grads, strict=True):
        try:
            assert_close(split, plain, rtol)
        except AssertionError as error:
            raise AssertionError(f"gradient of {name}: {error}") from None


@pytest.mark.parametrize("layer", ["interaction", "attention"])
def test_a_processor_of_split_layers_equals_the_plain_stack(layer):
    torch.manual_seed(3)
    processor = Processor(LATENT, 4, layer=layer).double()
    x, edge_index, edge_attr = graph(40, 400, 35, torch.float64, seed=4)

    with torch.no_grad():
        x_split, edge_split = processor(x, edge_index, edge_attr)
        x_plain, edge_plain = x, edge_attr
        for module in processor.layers:
            x_plain, edge_plain = plain_layer(module, x_plain, edge_index, edge_plain)

    assert_close(x_split, x_plain, 1e-12)
    assert_close(edge_split, edge_plain, 1e-12)


def test_the_split_keeps_the_parameters_and_state_dict_keys():
    layer = InteractionNetwork(LATENT, mlp_layers=2)
    assert layer.edge_mlp[0].weight.shape == (LATENT, 3 * LATENT)
    assert sorted(layer.state_dict()) == sorted(
        f"{mlp}.{index}.{kind}"
        for mlp in ("edge_mlp", "node_mlp")
        for index in (0, 2, 4, 5)
        for kind in ("weight", "bias")
    )
