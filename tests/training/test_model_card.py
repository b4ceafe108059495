"""The model card: what a checkpoint's model does and was trained on, and the range warning."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import torch

from granular_pyg.inference import load_simulator
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scenes import make_hopper
from granular_pyg.training.model_card import model_card, outside_training


def _card(radius=0.0015, friction=(0.4, 0.6)):
    scenes = []
    for f in friction:
        scene = make_hopper(particle_radius=radius)
        scene = dataclasses.replace(
            scene, materials=dataclasses.replace(scene.materials, friction=f)
        )
        scenes.append((scene, np.full(10, radius)))
    return model_card(0.02, 0.0075, "both", 5, 8, scenes)


def test_the_card_records_step_cutoff_and_the_training_ranges():
    card = _card()
    assert card["dt_s"] == 0.02 and card["cutoff_m"] == 0.0075 and card["variant"] == "both"
    data = card["training_data"]
    assert data["scene_kinds"] == ["hopper"] and data["trajectories"] == 2
    assert data["materials"]["friction"] == [0.4, 0.6]
    assert data["particle_radius_m"] == [0.0015, 0.0015] and data["particles"] == [10, 10]


def test_a_trajectory_outside_the_ranges_is_named_with_value_and_range():
    truth = read_trajectory(sample_files("hopper", "test")[0])
    inside = _card(radius=float(truth.radii[0]), friction=(0.4, 0.6))
    assert outside_training(inside, truth) == []
    narrow = _card(radius=0.001, friction=(0.6, 0.7))
    found = outside_training(narrow, truth)
    assert any(
        m.startswith("particle radius 0.0015-0.0015 m") and "0.001-0.001" in m for m in found
    )
    assert any(m.startswith("friction 0.5: ") and "0.6-0.7" in m for m in found)
    drum = read_trajectory(sample_files("drum", "test")[0])
    assert any("scene kind 'drum'" in m for m in outside_training(inside, drum))
    assert outside_training({}, truth) == [] and outside_training(None, truth) == []


def test_the_shipped_models_carry_their_card_and_real_step():
    for name, k in (("hopper", 8), ("drum", 4)):
        sim, config = load_simulator(f"pretrained:{name}")
        card = config["model_card"]
        assert abs(card["dt_s"] - float(sim.dt)) < 1e-12 and card["frames_per_step"] == k
        assert abs(config["model"]["dt"] - float(sim.dt)) < 1e-12
        assert card["training_data"]["scene_kinds"] == [name]


def test_rollout_warns_outside_the_training_data(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "granular_pyg.rollout", "ckpt=pretrained:hopper",
         f"trajectory={sample_files('drum', 'test')[0]}", "steps=1"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "warning: " in done.stderr and "scene kind 'drum'" in done.stderr


def test_a_training_checkpoint_stores_the_learned_step_and_its_card(tmp_path):
    from granular_pyg.config import compose
    from granular_pyg.train import train

    cfg = compose(
        "train",
        [
            "model.latent=16",
            "data.batch_size=1",
            "data.frames_per_step=8",
            "data.train_samples_per_epoch=2",
            "data.val_samples=1",
            "trainer.max_steps=2",
            "trainer.max_epochs=1",
            "rollout_validation.every_n_epochs=1000",
        ],
    )
    train(cfg, out_dir=tmp_path)
    ckpt = tmp_path / "checkpoints" / "last.ckpt"
    saved = torch.load(ckpt, weights_only=False)
    assert abs(saved["config"]["model"]["dt"] - 0.02) < 1e-9
    assert abs(saved["model_card"]["dt_s"] - 0.02) < 1e-9
    assert saved["model_card"]["training_data"]["scene_kinds"] == ["hopper"]
