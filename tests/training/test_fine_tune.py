"""Fine-tuning (``init=``): the run starts from the initial model's weights and normalisation,
keeps its learned step, widens its card, and refuses data it cannot use."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.inference import load_simulator
from granular_pyg.train import train
from granular_pyg.training.fine_tune import merge_cards, with_initial_model

FINETUNE = [
    "+experiment=finetune",
    "data.root=null",
    "trainer.enable_progress_bar=false",
    "trainer.max_time=null",
]


def test_a_fine_tuning_run_starts_from_the_initial_weights_and_normalisation(tmp_path):
    # lr 1e-12: one optimiser step moves a weight by ~1e-12, so the saved model is the initial one
    cfg = compose(
        "train",
        [
            *FINETUNE,
            "trainer.max_steps=1",
            "optim.lr=1e-12",
            "optim.lr_final=1e-12",
            "checkpoint.every_n_train_steps=1",
            "rollout_validation.every_n_epochs=1000",
        ],
    )
    train(cfg, tmp_path)
    tuned, tuned_cfg = load_simulator(tmp_path / "checkpoints" / "last.ckpt")
    initial, initial_cfg = load_simulator("pretrained:hopper")
    a, b = tuned.state_dict(), initial.state_dict()
    assert a.keys() == b.keys()
    buffers = {name for name, _ in initial.named_buffers()}
    assert {"dt"} <= buffers and len(buffers) > 1  # the normalisation statistics and the step
    for key in a:
        if key in buffers:
            assert torch.equal(a[key], b[key]), key
        else:
            assert torch.allclose(a[key], b[key], rtol=0, atol=1e-9), key
    assert tuned_cfg["model"]["latent"] == initial_cfg["model"]["latent"]
    assert tuned_cfg["model_card"]["fine_tuned_from"] == "pretrained:hopper"


def test_the_learned_step_sets_frames_per_step_and_the_model_comes_from_the_checkpoint():
    cfg, ckpt = with_initial_model(compose("train", [*FINETUNE, "model.latent=8"]))
    assert cfg.model.latent == ckpt["config"]["model"]["latent"] != 8
    # the learned step is the shipped model's: k frames of the bundled hopper
    from granular_pyg.io import read_trajectory
    from granular_pyg.samples import sample_files

    frame_dt = read_trajectory(sample_files("hopper")[0]).frame_dt
    assert cfg.data.frames_per_step * frame_dt == pytest.approx(cfg.model.dt, rel=1e-9)
    assert cfg.data.frames_per_step > 1
    assert cfg.data.history == cfg.model.history


def test_a_frame_spacing_the_step_is_not_a_multiple_of_is_refused(tmp_path):
    import dataclasses

    from granular_pyg.io import read_trajectory, write_trajectory
    from granular_pyg.samples import sample_files

    traj = read_trajectory(sample_files("hopper")[0])
    scene = dataclasses.replace(traj.scene, frame_dt=0.03)
    odd = dataclasses.replace(traj, scene=scene, times=traj.times * 1.5)
    write_trajectory(odd, tmp_path / "odd.h5")
    cfg = compose("train", [*FINETUNE, f"+data.trajectories={{train: [{tmp_path / 'odd.h5'}]}}"])
    with pytest.raises(InputError, match=r"not a whole multiple of the new data's frame spacing"):
        with_initial_model(cfg)


def test_a_missing_initial_model_is_named():
    with pytest.raises(InputError, match=r"no pretrained model 'nope'"):
        with_initial_model(compose("train", [*FINETUNE, "init=pretrained:nope"]))


def test_the_card_of_a_fine_tuned_model_covers_both_datasets():
    old = {
        "training_data": {
            "trajectories": 4,
            "scene_kinds": ["hopper"],
            "particle_radius_m": [0.001, 0.0015],
            "particles": [500, 900],
            "frame_dt_s": [0.02, 0.02],
            "materials": {"friction": [0.3, 0.5]},
        }
    }
    new = {
        "dt_s": 0.02,
        "training_data": {
            "trajectories": 2,
            "scene_kinds": ["mesh"],
            "particle_radius_m": [0.0012, 0.002],
            "particles": [1500, 1500],
            "frame_dt_s": [0.0025, 0.0025],
            "materials": {"friction": [0.6, 0.6]},
        },
    }
    card = merge_cards(old, new, "pretrained:hopper")
    data = card["training_data"]
    assert data["particle_radius_m"] == [0.001, 0.002]
    assert data["particles"] == [500, 1500]
    assert data["frame_dt_s"] == [0.0025, 0.02]
    assert data["materials"]["friction"] == [0.3, 0.6]
    assert data["scene_kinds"] == ["hopper", "mesh"]
    assert data["trajectories"] == 6
    assert card["dt_s"] == 0.02 and card["fine_tuned_from"] == "pretrained:hopper"
