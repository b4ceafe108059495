"""The equivariant processor's ``wall_sum``: each step also sums the messages from wall nodes.
Switched on for a trained model (``init=... model.processor.wall_sum=true``) its weights start
at zero: the model without it, exactly. Its symmetries (turns, mirrors, re-meshing) are
checked in ``tests/test_symmetries.py``, whose equivariant models have it."""

from __future__ import annotations

import torch

from granular_pyg.checkpoint.fine_tune import with_wall_sum
from granular_pyg.checkpoint.saved_config import migrate_config
from granular_pyg.nn import HorizontalEquivariantProcessor
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import LearnedSimulator, ParticleProps
from tests.test_symmetries import _window


def _equivariant(wall_sum: bool) -> LearnedSimulator:
    torch.manual_seed(11)
    sim = LearnedSimulator(
        HorizontalEquivariantProcessor(latent=24, num_steps=2, channels=6, wall_sum=wall_sum),
        radius=0.0075,
        normals="both",
        latent=24,
        dt=0.005,
        contact_feature=True,
        radius_feature=True,
        wall_nodes="patch",
    )
    sim.set_normalization([0.01, -0.02, -0.2], [0.1, 0.12, 0.3], [0.3, 0.1, -9.8], [5.0, 4.0, 8.0])
    return sim.double().eval()


def test_switching_the_wall_sum_on_keeps_the_trained_model_exactly():
    plain, summed = _equivariant(False), _equivariant(True)
    state = {f"sim.{k}": v for k, v in plain.state_dict().items()}
    widened = with_wall_sum(state, 24)
    assert with_wall_sum(widened, 24).keys() == widened.keys()
    for key, value in with_wall_sum(widened, 24).items():  # already widened: unchanged
        assert torch.equal(value, widened[key])
    summed.load_state_dict({k[len("sim.") :]: v for k, v in widened.items()})
    traj, seq, t, present = _window("hopper", 30)
    props = ParticleProps.of(traj)[present]
    walls = WallSet(traj.scene)
    with torch.no_grad():
        a = plain.predict_acceleration(seq, walls, t, props=props)
        b = summed.predict_acceleration(seq, walls, t, props=props)
    assert torch.equal(a, b)
    # the new inputs are live: a wall-sum weight moves the particles next to walls only
    layer = summed.model.processor.layers[0].node_mlp[0]
    with torch.no_grad():
        layer.weight[:, -24:] = 0.5
        c = summed.predict_acceleration(seq, walls, t, props=props)
    changed = (c - a).abs().amax(dim=1) > 0
    assert changed.any() and not changed.all()


def test_an_older_equivariant_checkpoint_reads_as_without_the_wall_sum():
    target = "granular_pyg.nn.HorizontalEquivariantProcessor"
    old = {"model": {"processor": {"_target_": target, "latent": 32}}}
    assert migrate_config(old)["model"]["processor"]["wall_sum"] is False
    new = {"model": {"processor": {"_target_": target, "wall_sum": True}}}
    assert migrate_config(new)["model"]["processor"]["wall_sum"] is True
    bgnn = {"model": {"processor": {"_target_": "granular_pyg.nn.Processor"}}}
    assert "wall_sum" not in migrate_config(bgnn)["model"]["processor"]
