"""Growing a trained equivariant model's processor (``init=... model.processor.num_steps=6``):
the appended steps start as the identity, so the grown model is the trained one exactly, and
their zeroed weights get gradients, so training opens them."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.checkpoint.fine_tune import with_initial_model, with_more_steps
from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.nn import HorizontalEquivariantProcessor
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator, ParticleProps
from tests.test_symmetries import _window


def _equivariant(num_steps: int) -> LearnedSimulator:
    torch.manual_seed(5)
    sim = LearnedSimulator(
        HorizontalEquivariantProcessor(latent=16, num_steps=num_steps, channels=4, wall_sum=True),
        radius=0.0075,
        normals="both",
        latent=16,
        dt=0.005,
        contact_feature=True,
        radius_feature=True,
        wall_nodes="patch",
    )
    sim.set_normalization([0.01, -0.02, -0.2], [0.1, 0.12, 0.3], [0.3, 0.1, -9.8], [5.0, 4.0, 8.0])
    return sim.double().eval()


def _grown(small: LearnedSimulator, num_steps: int) -> LearnedSimulator:
    state = with_more_steps({f"sim.{k}": v for k, v in small.state_dict().items()}, num_steps)
    big = _equivariant(num_steps)
    big.load_state_dict({k[len("sim.") :]: v for k, v in state.items()}, strict=True)
    return big


def test_added_steps_keep_the_trained_model_exactly_and_open_under_training():
    small = _equivariant(2)
    big = _grown(small, 4)
    traj, seq, t, present = _window("hopper", 30)
    props = ParticleProps.of(traj)[present]
    walls = WallSet(traj.scene)
    with torch.no_grad():
        a = small.predict_acceleration(seq, walls, t, props=props)
        b = big.predict_acceleration(seq, walls, t, props=props)
    assert torch.equal(a, b)
    # the zeroed weights of the new steps get gradients: training can open them
    graph = big.build_graph(seq, walls, t, props=props)
    big.train()
    big(graph).square().sum().backward()
    for step in (2, 3):
        layer = big.model.processor.layers[step]
        assert layer.node_mlp[-1].weight.grad.abs().sum() > 0
        assert layer.channel_mix.weight.grad.abs().sum() > 0
    # the edge MLPs open next: once a node LayerNorm has moved, their gradients flow
    last = big.model.processor.layers[3]
    assert last.edge_mlp[-1].weight.grad.abs().sum() == 0
    with torch.no_grad():
        last.node_mlp[-1].weight.fill_(1e-3)
    big.zero_grad()
    big(graph).square().sum().backward()
    assert last.edge_mlp[-1].weight.grad.abs().sum() > 0


def test_growing_to_the_same_number_of_steps_changes_nothing():
    small = _equivariant(3)
    state = {f"sim.{k}": v for k, v in small.state_dict().items()}
    same = with_more_steps(state, 3)
    assert same.keys() == state.keys()
    assert all(torch.equal(same[k], state[k]) for k in state)


FINETUNE = ["+experiment=finetune", "data.root=null", "trainer.max_time=null"]


def test_fine_tuning_adds_steps_to_an_equivariant_model():
    overrides = [*FINETUNE, "init=pretrained:fast_hopper", "model.processor.num_steps=5"]
    cfg, ckpt = with_initial_model(compose("train", overrides), overrides)
    assert cfg.model.processor.num_steps == 5
    saved = ckpt["config"]["model"]["processor"]["num_steps"]
    prefix = "sim.model.processor.layers."
    steps = {
        int(k[len(prefix) :].split(".")[0]) for k in ckpt["state_dict"] if k.startswith(prefix)
    }
    assert saved < 5 and steps == set(range(5))


@pytest.mark.parametrize(
    ("init", "steps", "match"),
    [
        ("pretrained:fast_hopper", 1, r"can add steps .* not remove them"),
        ("pretrained:hopper", 12, r"only the equivariant processor can grow"),
    ],
)
def test_fewer_steps_or_another_processor_are_refused(init, steps, match):
    overrides = [*FINETUNE, f"init={init}", f"model.processor.num_steps={steps}"]
    with pytest.raises(InputError, match=match):
        with_initial_model(compose("train", overrides), overrides)
