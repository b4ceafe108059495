"""Pretrained checkpoints: shipped small, loadable by name, exported without optimiser state."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.io import read_trajectory
from granular_pyg.pretrained import PRETRAINED, resolve_checkpoint
from granular_pyg.pretrained.export import MAX_BYTES, export
from granular_pyg.samples import sample_files

#: Each shipped model and the bundled sample it is tested on.
SAMPLE = {"hopper": "hopper", "drum": "drum", "fast_hopper": "hopper", "fast_drum": "drum"}


def test_every_shipped_model_is_tested():
    assert set(SAMPLE) == set(PRETRAINED)


@pytest.mark.parametrize("name", sorted(SAMPLE))
def test_each_shipped_model_is_small_and_rolls_out_its_bundled_test_trajectory(name):
    path = resolve_checkpoint(f"pretrained:{name}")
    assert path.stat().st_size <= MAX_BYTES
    sim, config = load_simulator(f"pretrained:{name}")
    assert config["model"]["normals"] == "both" and config["data"]["sample"] == SAMPLE[name]
    truth = read_trajectory(sample_files(SAMPLE[name], "test")[0])
    pred = rollout_trajectory(sim, truth, steps=3, progress=False)
    assert pred.num_frames == sim.history + 1 + 3
    present = int(np.isfinite(pred.positions[-1]).all(axis=1).sum())
    # the hopper discharges through its outflow; the closed drum keeps every particle
    assert present == truth.num_particles if SAMPLE[name] == "drum" else present > 0


def test_unknown_pretrained_name_lists_the_available_ones():
    available = (
        r"available: pretrained:drum, pretrained:fast_drum, pretrained:fast_hopper, "
        r"pretrained:hopper"
    )
    with pytest.raises(InputError, match=available):
        resolve_checkpoint("pretrained:silo")
    assert str(resolve_checkpoint("runs/x/last.ckpt")) == "runs/x/last.ckpt"


def test_export_keeps_config_and_weights_only(tmp_path):
    cfg = compose("train", ["model.latent=16", "data.root=data/somewhere", "model.sleep=false"])
    sim = instantiate(cfg.model)
    full = {
        "config": OmegaConf.to_container(cfg, resolve=True),
        "state_dict": {f"sim.{k}": v for k, v in sim.state_dict().items()},
        "optimizer_states": [{"big": torch.zeros(1000)}],
        "global_step": 7,
    }
    torch.save(full, tmp_path / "last.ckpt")
    out = export(tmp_path / "last.ckpt", "drum", "drum", "a note", folder=tmp_path)
    assert out.name == PRETRAINED["drum"]
    slim = torch.load(out, weights_only=False)
    assert set(slim) == {"config", "state_dict", "model_card", "pretrained"}
    assert slim["config"]["data"]["sample"] == "drum" and slim["config"]["data"]["root"] is None
    assert slim["pretrained"]["trained_on"]["root"] == "data/somewhere"
    assert slim["pretrained"]["global_step"] == 7
    loaded, _ = load_simulator(out)
    for name, value in sim.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], value)
    # a shipped model re-exported with sleeping on keeps its weights and its record
    again = export(out, "drum", "drum", sleep=True, out=tmp_path / "sleeping.ckpt")
    slept = torch.load(again, weights_only=False)
    assert slept["config"]["model"]["sleep"] is True
    assert slept["pretrained"] == slim["pretrained"]
    assert slept["config"]["data"] == slim["config"]["data"]
    assert all(torch.equal(slept["state_dict"][k], v) for k, v in slim["state_dict"].items())
    assert load_simulator(again)[0].sleep and not load_simulator(out)[0].sleep
    # the scene's own frame and a node per surface patch: rules without weights, likewise
    framed = export(
        out, "drum", "drum", canonical_frame=True, wall_nodes="patch", out=tmp_path / "f.ckpt"
    )
    turned, _ = load_simulator(framed)
    assert turned.canonical_frame and turned.wall_nodes.per == "patch"
    assert not load_simulator(out)[0].canonical_frame
    with pytest.raises(InputError, match="--wall-nodes"):
        export(out, "drum", "drum", wall_nodes="cell", out=tmp_path / "g.ckpt")


@pytest.mark.parametrize("name", sorted(SAMPLE))
def test_the_shipped_models_roll_out_as_stored(name):
    """The shipped models give the stored rollout (4 learned steps on the bundled test
    trajectory, recorded when each model was shipped) to 1e-6 m."""
    reference = np.load(Path(__file__).parent / "data" / "pretrained_rollout_reference.npz")
    sim, _ = load_simulator(f"pretrained:{name}")
    truth = read_trajectory(sample_files(SAMPLE[name], "test")[0])
    pred = rollout_trajectory(sim, truth, steps=4, progress=False)
    np.testing.assert_allclose(pred.positions[-4:], reference[name], rtol=0, atol=1e-6)
