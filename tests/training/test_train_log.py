"""A fine-tuning run's feedback: validation rollouts by optimiser steps or wall time (not only
every n epochs), each objective's loss logged apart, and a train.log with a line per epoch
and per rollout."""

from __future__ import annotations

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from granular_pyg.config import compose
from granular_pyg.errors import InputError
from granular_pyg.train import train
from granular_pyg.training.callbacks import RolloutValidation


def _cfg(*extra: str):
    return compose(
        "train",
        [
            "model.latent=16",
            "data.batch_size=1",
            "trainer.enable_progress_bar=true",  # a terminal's run: the log still fills
            "data.train_samples_per_epoch=3",
            "data.val_samples=2",
            "trainer.max_steps=6",
            "trainer.max_epochs=-1",
            "trainer.log_every_n_steps=1",
            "checkpoint.every_n_train_steps=100",
            "objective=unrolled",
            "objective.parts.unrolled.steps=2",
            "rollout_validation.every_n_epochs=null",
            "rollout_validation.every_n_steps=2",
            "rollout_validation.steps=2",
            *extra,
        ],
    )


def test_rollouts_by_steps_and_each_objectives_loss_reach_the_log(tmp_path):
    train(_cfg(), tmp_path)
    lines = (tmp_path / "train.log").read_text().splitlines()
    assert lines[0].startswith("training from step 0")
    epochs = [line for line in lines if line.startswith("epoch ")]
    rollouts = [line for line in lines if line.startswith("rollout  step ")]
    assert len(epochs) == 2  # 6 steps of 3 windows
    assert [line.split()[2] for line in rollouts] == ["2", "4", "6"]
    assert all("val_rollout/emd " in line for line in rollouts)
    # Each objective apart, over the batches it took (the mixture: unrolled half of them).
    assert any("train/loss_unrolled" in line or "train/loss_one_step" in line for line in epochs)
    acc = EventAccumulator(str(tmp_path / "tensorboard"), size_guidance={"scalars": 0})
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert {"val_rollout/emd", "train/loss"} <= tags
    assert tags & {"train/loss_unrolled", "train/loss_one_step"}
    assert len(acc.Scalars("val_rollout/emd")) >= 3


def test_rollout_triggers_must_be_positive_or_off():
    with pytest.raises(InputError, match=r"rollout_validation.every_seconds: expected a positive"):
        RolloutValidation(every_seconds=0)
    RolloutValidation(every_n_epochs=None, every_seconds=240.0)  # fine-tuning's setting


def test_fine_tuning_validates_by_wall_time():
    cfg = compose("train", ["+experiment=finetune", "data.root=x"])
    assert cfg.rollout_validation.every_n_epochs is None
    assert 0 < cfg.rollout_validation.every_seconds <= 300
