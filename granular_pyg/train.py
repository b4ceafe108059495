"""``python -m granular_pyg.train model=v3``: train a learned simulator (Hydra + Lightning).

Outputs (run folder ``outputs/train/<time>/``, or ``multirun/train/<time>/<n>_<overrides>/``):
``checkpoints/`` (``last.ckpt`` + periodic ones), ``tensorboard/`` (losses, validation rollout
metrics and figures), ``.hydra/`` (the composed config). ``ckpt_path=<file>`` resumes exactly.
"""

from __future__ import annotations

import sys
from pathlib import Path

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from granular_pyg.checkpoint import (
    DERIVED_KEYS,
    RESUME_KEYS,
    build_model,
    card_of_trajectories,
    check_resume,
    saved_config,
    to_plain,
)
from granular_pyg.checkpoint.fine_tune import (
    load_initial_weights,
    merge_cards,
    with_initial_model,
)
from granular_pyg.cli import command, task_overrides
from granular_pyg.errors import finite_number, whole_number
from granular_pyg.progress import show_progress
from granular_pyg.training import AtomicCheckpointIO, RolloutValidation, SimulatorModule
from granular_pyg.training.epoch_log import EpochLog

__all__ = ["DERIVED_KEYS", "RESUME_KEYS", "train"]

#: The resume check lives with the checkpoint (kept here under its old names for older imports).
_check_resume = check_resume


class _SaveConfig(L.Callback):
    """Stores the run's config (plain dicts, with the learned step the data set) and its model
    card in every checkpoint (:func:`granular_pyg.checkpoint.saved_config`)."""

    def __init__(self, cfg: DictConfig, card: dict) -> None:
        self.config = saved_config(cfg, card)
        self.card = to_plain(card)

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        checkpoint["config"] = self.config
        checkpoint["model_card"] = self.card


def _card(cfg: DictConfig, sim, datamodule) -> dict:
    """The model card of ``sim`` trained on ``datamodule``'s training trajectories."""
    return card_of_trajectories(
        datamodule.train_set.trajs,
        float(sim.dt),
        float(sim.radius_graph.radius),
        str(cfg.model.get("normals")),
        sim.history,
        datamodule.frames_per_step,
    )


def train(cfg: DictConfig, out_dir: str | Path | None = None) -> dict[str, float]:
    """Train as ``cfg`` says; returns the final logged metrics (``train/loss``, ``val/loss``...).

    Args:
        cfg: the composed ``conf/train.yaml``.
        out_dir: run folder; the Hydra run folder when called from the command line.
    """
    out = Path(out_dir or HydraConfig.get().runtime.output_dir)
    initial = None
    if cfg.get("init"):
        cfg, initial = with_initial_model(cfg, task_overrides())
        print(f"fine-tuning {cfg.init}: its model, weights and normalisation; a new optimiser")
    if cfg.ckpt_path:
        check_resume(cfg.ckpt_path, cfg)
    finite_number("data.noise_std", cfg.data.get("noise_std", 0.0), minimum=0.0)
    L.seed_everything(cfg.seed, workers=True)
    torch.set_num_threads(whole_number("threads", cfg.threads, minimum=1))
    objective = instantiate(cfg.objective)
    datamodule = instantiate(cfg.data)
    datamodule.prepare(objective)  # the learned step: data.frames_per_step x frame spacing
    if initial is not None:  # the model section is the checkpoint's: its own classes only
        model = OmegaConf.to_container(cfg.model, resolve=True)
        sim = build_model(model | {"dt": datamodule.dt}, f"init: {cfg.init}", initial["state_dict"])
    else:
        sim = instantiate(cfg.model, dt=datamodule.dt)
    if cfg.get("compile"):
        sim.compile_for_training()
    datamodule.attach(sim, objective)
    card = _card(cfg, sim, datamodule)
    if initial is not None:
        load_initial_weights(sim, initial)
        card = merge_cards(initial.get("model_card") or {}, card, str(cfg.init))
    module = SimulatorModule(sim, objective, **cfg.optim, seed=cfg.seed)
    logger = instantiate(cfg.logger, save_dir=str(out)) if cfg.logger else False
    callbacks = [
        L.pytorch.callbacks.ModelCheckpoint(dirpath=out / "checkpoints", **cfg.checkpoint),
        RolloutValidation(**cfg.rollout_validation),
        _SaveConfig(cfg, card),
    ]
    if logger:
        callbacks.append(L.pytorch.callbacks.LearningRateMonitor(logging_interval="step"))
    # a bar per batch in a terminal; one line per epoch in a log file
    bar = show_progress(cfg.trainer.get("enable_progress_bar", True), sys.stdout)
    # train.log: a line per epoch and per validation rollout, also printed without a bar
    callbacks.append(EpochLog(out / "train.log", echo=not bar))
    trainer = instantiate(
        cfg.trainer,
        enable_progress_bar=bar,
        logger=logger,
        callbacks=callbacks,
        default_root_dir=str(out),
        plugins=[AtomicCheckpointIO()],
    )
    trainer.fit(module, datamodule=datamodule, ckpt_path=cfg.ckpt_path)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
    if trainer.is_global_zero:
        print(f"run folder: {out}")
        print(f"checkpoints: {out / 'checkpoints'}")
        if logger:
            print(f"TensorBoard: tensorboard --logdir {out / 'tensorboard'}")
        for name in ("train/loss", "val/loss", "val_rollout/emd"):
            if name in metrics:
                print(f"{name}: {metrics[name]:.4g}")
    return metrics


@command("train")
def main(cfg: DictConfig) -> float | None:
    metrics = train(cfg)
    return metrics.get("val/loss")


if __name__ == "__main__":
    main()
