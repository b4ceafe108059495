"""The network zoo: message-passing layers, processor, encode-process-decode, Hydra presets."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch_geometric.data import Batch, Data

from granular_pyg.errors import InputError
from granular_pyg.nn import (
    MLP,
    AttentionInteractionNetwork,
    EncodeProcessDecode,
    InteractionNetwork,
    Processor,
)

PRESETS = Path(__file__).resolve().parents[2] / "conf" / "model" / "processor"

LATENT = 16
NODE_IN, EDGE_IN, OUT = 5, 4, 3

#: (layer, aggr) of every processor kind of the zoo.
KINDS = [("interaction", "sum"), ("interaction", "mean"), ("attention", "sum")]
KIND_IDS = ["sum", "mean", "attention"]


def random_graph(
    num_nodes: int = 12, num_edges: int = 40, width: int = LATENT, edge_width: int = LATENT, seed=0
):
    """``x [N, width]``, ``edge_index [2, E]``, ``edge_attr [E, edge_width]`` (float32)."""
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(num_nodes, width, generator=gen)
    edge_index = torch.randint(0, num_nodes, (2, num_edges), generator=gen)
    edge_attr = torch.randn(num_edges, edge_width, generator=gen)
    return x, edge_index, edge_attr


def make_model(layer: str, aggr: str, num_steps: int = 2, seed: int = 0) -> EncodeProcessDecode:
    torch.manual_seed(seed)
    processor = Processor(LATENT, num_steps, layer=layer, aggr=aggr, heads=4)
    return EncodeProcessDecode(NODE_IN, EDGE_IN, OUT, processor, latent=LATENT)


# -- edge updates ---------------------------------------------------------------------------


@pytest.mark.parametrize("layer", ["interaction", "attention"])
def test_edge_latents_change_at_every_step_and_feed_the_next(layer):
    torch.manual_seed(0)
    processor = Processor(LATENT, 3, layer=layer)
    x, edge_index, edge_attr = random_graph()
    seen = []  # (edge_attr in, edge_attr out) of each layer, as the processor runs it
    for module in processor.layers:
        module.register_forward_hook(lambda _m, args, out: seen.append((args[2], out[1])))

    _, final_edges = processor(x, edge_index, edge_attr)

    assert len(seen) == 3
    for step, (before, after) in enumerate(seen):
        assert after.shape == before.shape
        assert not torch.allclose(after, before), f"step {step} left the edge latents unchanged"
    for step in range(2):
        assert seen[step + 1][0] is seen[step][1], (
            f"step {step + 1} did not get step {step}'s edges"
        )
    assert seen[0][0] is edge_attr
    assert torch.equal(final_edges, seen[-1][1])


# -- gradients --------------------------------------------------------------------------------


@pytest.mark.parametrize(("layer", "aggr"), KINDS, ids=KIND_IDS)
def test_gradients_reach_every_parameter(layer, aggr):
    model = make_model(layer, aggr)
    x, edge_index, edge_attr = random_graph(width=NODE_IN, edge_width=EDGE_IN)
    weights = torch.randn(x.shape[0], OUT, generator=torch.Generator().manual_seed(1))

    (model(x, edge_index, edge_attr) * weights).sum().backward()

    for name, param in model.named_parameters():
        assert param.grad is not None, f"{name} got no gradient"
        assert bool(param.grad.abs().gt(0).any()), f"{name} got an all-zero gradient"


# -- symmetries -------------------------------------------------------------------------------


@pytest.mark.parametrize(("layer", "aggr"), KINDS, ids=KIND_IDS)
def test_permuting_nodes_and_edges_permutes_the_output(layer, aggr):
    model = make_model(layer, aggr).eval()
    x, edge_index, edge_attr = random_graph(width=NODE_IN, edge_width=EDGE_IN)
    gen = torch.Generator().manual_seed(2)
    perm = torch.randperm(x.shape[0], generator=gen)  # new node k is old node perm[k]
    edge_perm = torch.randperm(edge_index.shape[1], generator=gen)
    new_label = torch.argsort(perm)  # old node i is new node new_label[i]

    out = model(x, edge_index, edge_attr)
    out_perm = model(x[perm], new_label[edge_index][:, edge_perm], edge_attr[edge_perm])

    torch.testing.assert_close(out_perm, out[perm], atol=1e-5, rtol=1e-5)


def four_against_one_graph():
    """Nodes 0 and 1 have equal latents; 0 has 4 identical incoming edges, 1 has one alike."""
    gen = torch.Generator().manual_seed(3)
    target, source = torch.randn(LATENT, generator=gen), torch.randn(LATENT, generator=gen)
    x = torch.stack([target, target] + [source] * 5)  # nodes 2..5 -> 0, node 6 -> 1
    edge_index = torch.tensor([[2, 3, 4, 5, 6], [0, 0, 0, 0, 1]])
    edge_attr = torch.randn(LATENT, generator=gen).expand(5, LATENT).clone()
    return x, edge_index, edge_attr


def test_mean_aggregation_ignores_the_number_of_identical_messages_and_sum_does_not():
    x, edge_index, edge_attr = four_against_one_graph()
    torch.manual_seed(0)
    mean_layer = InteractionNetwork(LATENT, aggr="mean")
    sum_layer = InteractionNetwork(LATENT, aggr="sum")
    sum_layer.load_state_dict(mean_layer.state_dict())  # same weights, only the aggregation differs

    with torch.no_grad():
        x_mean, _ = mean_layer(x, edge_index, edge_attr)
        x_sum, _ = sum_layer(x, edge_index, edge_attr)

    torch.testing.assert_close(x_mean[0], x_mean[1], atol=1e-6, rtol=0)
    assert not torch.allclose(x_sum[0], x_sum[1], atol=1e-3)
    torch.testing.assert_close(x_sum[1], x_mean[1], atol=1e-6, rtol=0)  # one message: same


def test_attention_weights_normalise_over_each_nodes_incoming_edges():
    x, edge_index, edge_attr = four_against_one_graph()
    torch.manual_seed(0)
    layer = AttentionInteractionNetwork(LATENT, heads=4)

    with torch.no_grad():
        x_new, e_new = layer(x, edge_index, edge_attr)
        alpha = layer.attention_weights(edge_index, e_new, x.shape[0])

    assert alpha.shape == (5, 4)
    torch.testing.assert_close(alpha[:4], torch.full((4, 4), 0.25))  # 4 identical edges
    torch.testing.assert_close(alpha[4], torch.ones(4))  # a single edge takes all
    torch.testing.assert_close(x_new[0], x_new[1], atol=1e-6, rtol=0)  # k does not matter


# -- structure ---------------------------------------------------------------------------------


@pytest.mark.parametrize("layer", ["interaction", "attention"])
def test_processor_layers_have_unshared_weights(layer):
    processor = Processor(LATENT, 3, layer=layer)

    layers = list(processor.layers)
    assert len(layers) == 3
    assert len({id(m) for m in layers}) == 3
    params = [list(m.parameters()) for m in layers]
    pointers = [p.data_ptr() for ps in params for p in ps]
    assert len(set(pointers)) == len(pointers), "two layers share a parameter tensor"
    first_weights = [m.edge_mlp[0].weight for m in layers]
    assert not torch.equal(first_weights[0], first_weights[1])
    assert not torch.equal(first_weights[1], first_weights[2])


def test_mlp_layout_follows_gns():
    encoder = MLP(5, 8, 7, num_hidden_layers=2, layer_norm=True)
    decoder = MLP(8, 8, 3, num_hidden_layers=2, layer_norm=False)

    kinds = [type(m).__name__ for m in encoder]
    assert kinds == ["Linear", "ReLU", "Linear", "ReLU", "Linear", "LayerNorm"]
    assert [type(m).__name__ for m in decoder] == kinds[:-1]
    assert encoder(torch.randn(4, 5)).shape == (4, 7)
    assert decoder(torch.randn(0, 8)).shape == (0, 3)


# -- degenerate graphs and batches --------------------------------------------------------------


@pytest.mark.parametrize(("layer", "aggr"), KINDS, ids=KIND_IDS)
def test_isolated_nodes_and_edgeless_graphs_give_finite_outputs(layer, aggr):
    model = make_model(layer, aggr).eval()
    x, _, _ = random_graph(num_nodes=6, width=NODE_IN)
    edge_index = torch.tensor([[0, 1, 2], [1, 2, 0]])  # nodes 3, 4, 5 isolated
    edge_attr = torch.randn(3, EDGE_IN)
    no_edges = torch.empty(2, 0, dtype=torch.long)

    with torch.no_grad():
        out = model(x, edge_index, edge_attr)
        out_empty = model(x, no_edges, torch.empty(0, EDGE_IN))
        out_alone = model(x[3:4], no_edges, torch.empty(0, EDGE_IN))

    assert out.shape == out_empty.shape == (6, OUT)
    assert bool(torch.isfinite(out).all())
    assert bool(torch.isfinite(out_empty).all())
    # an isolated node sees nothing of the rest of the graph
    torch.testing.assert_close(out[3:], out_empty[3:])
    torch.testing.assert_close(out[3:4], out_alone)


@pytest.mark.parametrize(("layer", "aggr"), KINDS, ids=KIND_IDS)
def test_a_batch_gives_the_outputs_of_its_graphs(layer, aggr):
    model = make_model(layer, aggr).eval()
    graphs = []
    for seed, (nodes, edges) in enumerate([(7, 20), (10, 35)]):
        x, edge_index, edge_attr = random_graph(nodes, edges, NODE_IN, EDGE_IN, seed=seed)
        graphs.append(Data(x=x, edge_index=edge_index, edge_attr=edge_attr))
    batch = Batch.from_data_list(graphs)

    with torch.no_grad():
        out = model(batch.x, batch.edge_index, batch.edge_attr)
        apart = [model(g.x, g.edge_index, g.edge_attr) for g in graphs]

    torch.testing.assert_close(out, torch.cat(apart), atol=1e-5, rtol=1e-5)


# -- bad input ---------------------------------------------------------------------------------


def test_bad_inputs_raise_input_error():
    model = make_model("interaction", "sum")
    x, edge_index, edge_attr = random_graph(width=NODE_IN, edge_width=EDGE_IN)

    with pytest.raises(InputError, match="x"):
        model(x[:, :-1], edge_index, edge_attr)
    with pytest.raises(InputError, match="edge_attr"):
        model(x, edge_index, edge_attr[:, :-1])
    with pytest.raises(InputError, match="edge_attr"):
        model(x, edge_index, edge_attr[:-1])
    with pytest.raises(InputError, match="edge_index"):
        model(x, edge_index[:1], edge_attr)
    with pytest.raises(InputError, match="int64"):
        model(x, edge_index.int(), edge_attr)
    with pytest.raises(InputError, match="must lie in"):
        model(x, edge_index + x.shape[0], edge_attr)
    with pytest.raises(InputError, match="float32"):
        model(x.double(), edge_index, edge_attr.double())
    with pytest.raises(InputError, match="x"):
        model.processor(x, edge_index, edge_attr)  # node features are not latents


def test_bad_settings_raise_input_error():
    with pytest.raises(InputError, match="divisible"):
        AttentionInteractionNetwork(10, heads=4)
    with pytest.raises(InputError, match="divisible"):
        Processor(10, 3, layer="attention", heads=4)
    with pytest.raises(InputError, match=r"\['attention', 'interaction'\].*'transformer'"):
        Processor(LATENT, 3, layer="transformer")
    with pytest.raises(InputError, match="aggr"):
        Processor(LATENT, 3, aggr="max")
    with pytest.raises(InputError, match="aggr"):
        Processor(LATENT, 3, layer="attention", aggr="mean")
    with pytest.raises(InputError, match="num_steps"):
        Processor(LATENT, 0)
    with pytest.raises(InputError, match="latent"):
        EncodeProcessDecode(NODE_IN, EDGE_IN, OUT, Processor(32, 1), latent=LATENT)
    with pytest.raises(InputError, match="hidden_dim"):
        MLP(3, 0, 3)


# -- Hydra presets ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("preset", "layer", "aggr", "num_steps", "layer_type"),
    [
        ("gns", "interaction", "sum", 10, InteractionNetwork),
        ("bgnn", "interaction", "mean", 3, InteractionNetwork),
        ("attention", "attention", "sum", 3, AttentionInteractionNetwork),
    ],
)
def test_presets_instantiate_to_their_processor(preset, layer, aggr, num_steps, layer_type):
    cfg = OmegaConf.load(PRESETS / f"{preset}.yaml")
    assert OmegaConf.to_container(cfg)["latent"] == "${..latent}"  # follows the model's latent
    cfg.latent = 32

    processor = instantiate(cfg)

    assert isinstance(processor, Processor)
    assert (processor.latent, processor.layer, processor.aggr) == (32, layer, aggr)
    assert processor.num_steps == len(processor.layers) == num_steps
    assert all(type(m) is layer_type for m in processor.layers)
    assert all(m.aggr == aggr and m.latent == 32 for m in processor.layers)
    if layer == "attention":
        assert all(m.heads == 4 for m in processor.layers)


@pytest.mark.parametrize("preset", ["gns", "bgnn", "attention"])
def test_preset_latent_interpolates_the_parent_model_latent(preset):
    model_cfg = OmegaConf.create(
        {"latent": 24, "processor": OmegaConf.load(PRESETS / f"{preset}.yaml")}
    )

    processor = instantiate(model_cfg.processor)

    assert processor.latent == 24
    assert processor.layers[0].edge_mlp[0].in_features == 3 * 24
