"""The blocked inference path (edges and MLP rows in cache-sized blocks, ReLU in place) gives
the numbers of the plain path, for every layer of the zoo and a whole model; training (with
autograd) keeps the plain path and its gradients."""

from __future__ import annotations

import pytest
import torch

import granular_pyg.nn.mlp as mlp_module
from granular_pyg.nn import EncodeProcessDecode, Processor
from granular_pyg.nn.mlp import MLP, row_chunks

LATENT = 16


def _graph(num_nodes=40, num_edges=333, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(num_nodes, 7, generator=g)
    edge_index = torch.randint(0, num_nodes, (2, num_edges), generator=g)
    edge_attr = torch.randn(num_edges, 4, generator=g)
    return x, edge_index, edge_attr


def test_fill_by_blocks_writes_each_block_of_rows_once(monkeypatch):
    monkeypatch.setattr(mlp_module, "ROW_CHUNK", 4)
    seen = []

    def block(rows):
        seen.append((rows.start, rows.stop))
        return torch.arange(rows.start, rows.stop, dtype=torch.float32).unsqueeze(1).repeat(1, 2)

    out = mlp_module.fill_by_blocks(torch.full((10, 2), -1.0), block)
    assert seen == [(0, 4), (4, 8), (8, 10)]
    assert torch.equal(out, torch.arange(10.0).unsqueeze(1).repeat(1, 2))


def test_row_chunks_cover_every_row_once():
    for rows, chunk in [(0, 4), (1, 4), (8, 4), (9, 4), (10, 3)]:
        covered = [i for s in row_chunks(rows, chunk) for i in range(rows)[s]]
        assert covered == list(range(rows))
        assert all(s.stop - s.start <= chunk for s in row_chunks(rows, chunk))


@pytest.mark.parametrize(
    ("layer", "aggr"), [("interaction", "sum"), ("interaction", "mean"), ("attention", "sum")]
)
def test_blocked_inference_equals_the_plain_path(monkeypatch, layer, aggr):
    torch.manual_seed(0)
    model = EncodeProcessDecode(
        7, 4, 3, Processor(latent=LATENT, num_steps=3, layer=layer, aggr=aggr), latent=LATENT
    ).eval()
    x, edge_index, edge_attr = _graph()
    with torch.inference_mode():
        plain = model(x, edge_index, edge_attr)  # 333 rows <= 4,096: one block
        monkeypatch.setattr(mlp_module, "ROW_CHUNK", 10)  # 34 blocks of edges, 4 of nodes
        blocked = model(x, edge_index, edge_attr)
    # float32 round-off: a matrix product over fewer rows may take another kernel
    torch.testing.assert_close(blocked, plain, rtol=1e-5, atol=1e-6)


def test_training_keeps_the_plain_path_and_its_gradients(monkeypatch):
    torch.manual_seed(0)
    model = EncodeProcessDecode(7, 4, 3, Processor(latent=LATENT, num_steps=2), latent=LATENT)
    x, edge_index, edge_attr = _graph()

    def grads():
        model.zero_grad()
        model(x, edge_index, edge_attr).square().sum().backward()
        return [p.grad.clone() for p in model.parameters()]

    plain = grads()
    monkeypatch.setattr(mlp_module, "ROW_CHUNK", 10)
    for a, b in zip(grads(), plain, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_an_mlp_over_many_rows_in_inference_equals_row_by_row_blocks(monkeypatch):
    torch.manual_seed(1)
    mlp = MLP(5, 8, 3, num_hidden_layers=2, layer_norm=True).eval()
    x = torch.randn(25, 5)
    with torch.no_grad():
        plain = torch.nn.Sequential.forward(mlp, x)
        monkeypatch.setattr(mlp_module, "ROW_CHUNK", 4)
        torch.testing.assert_close(mlp(x), plain, rtol=1e-5, atol=1e-6)


def test_under_bf16_autocast_the_blocked_path_stores_edge_latents_in_bf16(monkeypatch):
    """The edge latents (the largest buffer) are kept in bfloat16 on the blocked path, node
    latents and the aggregation stay float32, and the output stays close to float32's."""
    torch.manual_seed(0)
    model = EncodeProcessDecode(
        7, 4, 3, Processor(latent=LATENT, num_steps=3, aggr="mean"), latent=LATENT
    ).eval()
    x, edge_index, edge_attr = _graph(num_edges=500)
    monkeypatch.setattr(mlp_module, "ROW_CHUNK", 64)
    with torch.inference_mode():
        exact = model(x, edge_index, edge_attr)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            stored = model.edge_encoder(edge_attr, store_in_autocast_dtype=True)
            mixed = model(x, edge_index, edge_attr)
    assert stored.dtype == torch.bfloat16 and stored.shape == (500, LATENT)
    # bfloat16 keeps 8 significant bits: outputs of order one agree to a few hundredths
    scale = exact.abs().max()
    assert (mixed.float() - exact).abs().max() < 0.05 * scale


def test_blocked_aggregation_equals_the_scatter_over_all_edges(monkeypatch):
    from granular_pyg.nn.interaction_network import InteractionNetwork

    torch.manual_seed(2)
    messages = torch.randn(97, LATENT)
    target = torch.randint(0, 13, (97,))
    target[target == 5] = 6  # node 5 receives nothing: it aggregates to zero
    monkeypatch.setattr(mlp_module, "ROW_CHUNK", 8)
    for aggr in ("sum", "mean"):
        layer = InteractionNetwork(LATENT, aggr=aggr)
        blocked = layer.aggregate_blocked(messages, target, 13)
        expected = torch.zeros(13, LATENT).index_add_(0, target, messages)
        if aggr == "mean":
            expected /= torch.bincount(target, minlength=13).clamp(min=1).unsqueeze(1)
        torch.testing.assert_close(blocked, expected, rtol=1e-6, atol=1e-6)
        assert blocked[5].abs().max() == 0
    half = layer.aggregate_blocked(messages.bfloat16(), target, 13)
    assert half.dtype == torch.float32
