"""Suite ``training``: training throughput (samples/s) per processor at its default size.

Each processor trains with the default config (``conf/train.yaml``: bundled hopper sample,
model v3, latent 128, batch size 2, noise on) through the real pipeline: windows -> graphs
(radius graph + wall nodes, built in the loader's collate) -> forward -> backward -> Adam.
The clock runs from the end of ``warmup`` optimiser steps to the end of ``warmup + steps``; a
sample is one window (one state of all particles of a trajectory), so samples/s = batch size x
steps / seconds. Validation, checkpoints and logging are off so that only training is timed.
"""

from __future__ import annotations

import time

import lightning as L
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from hydra.utils import instantiate

from granular_pyg.bench.report import SuiteResult
from granular_pyg.config import compose
from granular_pyg.training import SimulatorModule


class _StepClock(L.Callback):
    """Wall time between the end of optimiser step ``warmup`` and the last one."""

    def __init__(self, warmup: int) -> None:
        self.warmup, self.start, self.end = warmup, None, None

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if trainer.global_step == self.warmup:
            self.start = time.perf_counter()
        self.end = time.perf_counter()


def _throughput(
    processor: str,
    steps: int,
    warmup: int,
    overrides: list[str],
    precision: str = "32-true",
    compiled: bool = False,
) -> dict:
    cfg = compose("train", [f"model/processor={processor}", *overrides])
    L.seed_everything(cfg.seed)
    sim = instantiate(cfg.model)
    if compiled:
        sim.compile_for_training()
    objective = instantiate(cfg.objective)
    data = instantiate(cfg.data)
    data.attach(sim, objective)
    module = SimulatorModule(sim, objective, **cfg.optim, seed=cfg.seed)
    clock = _StepClock(warmup)
    trainer = L.Trainer(
        accelerator="cpu",
        max_steps=warmup + steps,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[clock],
        precision=precision,
    )
    trainer.fit(module, datamodule=data)
    seconds = clock.end - clock.start
    return {
        "processor": processor,
        "precision": precision + ("+compile" if compiled else ""),
        "parameters": sum(p.numel() for p in sim.parameters()),
        "batch_size": data.batch_size,
        "steps": steps,
        "seconds": seconds,
        "samples_per_s": data.batch_size * steps / seconds,
        "ms_per_step": 1e3 * seconds / steps,
    }


def run(
    processors: tuple[str, ...] = ("gns", "bgnn", "attention"),
    steps: int = 20,
    warmup: int = 3,
    overrides: tuple[str, ...] = (),
    repeats: int = 1,
    precisions: tuple[str, ...] = ("32-true",),
    compiled: tuple[bool, ...] = (False,),
) -> SuiteResult:
    """Run the suite; see the module docstring. ``precisions``: Lightning's (``32-true``,
    ``bf16-mixed``: matrix products in bfloat16 under autocast), a row each per processor;
    ``compiled``: eager and/or ``torch.compile``d training steps (a row each; the compilation
    falls in the warm-up steps). ``repeats`` is unused (one timed window)."""
    rows = [
        _throughput(p, steps, warmup, list(overrides), str(precision), bool(c))
        for p in processors
        for precision in precisions
        for c in compiled
    ]
    results = {
        f"training/{r['processor']}/{r['precision']}/samples_per_s": r["samples_per_s"]
        for r in rows
    }
    notes = (
        f"Default training config on the bundled hopper sample, {steps} optimiser steps timed "
        f"after {warmup} warm-up steps; overrides: {list(overrides) or 'none'}."
    )
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.bar(
        [f"{r['processor']}\n{r['precision']}" for r in rows], [r["samples_per_s"] for r in rows]
    )
    ax.set_ylabel("training samples / s")
    ax.set_title("Training throughput (CPU)")
    fig.tight_layout()
    return SuiteResult(rows, results, [], fig, notes)
