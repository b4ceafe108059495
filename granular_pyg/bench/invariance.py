"""Suite ``invariance``: the same run described differently must give the same flow.

Each model is rolled out (network alone unless ``wall_guard``) over one recorded LIGGGHTS
trajectory and over its variants (:data:`~granular_pyg.evaluation.variants.VARIANTS`: turned
45 and 90 degrees and by a seeded random angle about gravity, mirrored, every wall triangle
split in 4 and in 16), each scored against its own equally transformed truth. The report
gives every metric per variant and its spread; the targets compare each variant with the
original: leaked particles within the original's + 0.5% of the particles, discharge-rate
error within 3 percentage points, drum angle error within 1 degree, EMD within 1.5x.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from granular_pyg.bench.report import SuiteResult, Target
from granular_pyg.bench.trajectories import resolve_trajectory
from granular_pyg.errors import InputError
from granular_pyg.evaluation import evaluate_pair
from granular_pyg.evaluation.variants import VARIANTS, variant
from granular_pyg.inference import available_steps, load_simulator, rollout_trajectory

#: Scalars reported per variant (those a scene cannot have are NaN and left out of targets).
METRICS = (
    "leaked_particles",
    "discharge_rate_rel_error",
    "discharged_fraction_error",
    "angle_of_repose_error_deg",
    "emd_mean",
)


def run(
    models: tuple[str, ...],
    trajectories: tuple[str, ...],
    variants: tuple[str, ...] = tuple(VARIANTS),
    steps: int | None = None,
    seed: int = 0,
    wall_guard: bool = False,
    repeats: int = 1,
) -> SuiteResult:
    """Run the suite (module docstring); ``trajectories[i]`` goes with ``models[i]``.

    Args:
        models: checkpoints (``pretrained:<name>`` or paths).
        trajectories: one per model: a trajectory file, or ``sample:hopper`` /
            ``sample:drum`` for the bundled test trajectory.
        variants: names from :data:`~granular_pyg.evaluation.variants.VARIANTS`; ``original``
            is always run first.
        steps: learned steps per rollout, at most as many as the trajectory holds; None: all.
        seed: seed of ``turn_random``'s angle.
        wall_guard: roll out with the wall guard (default: the network alone).
        repeats: unused (every rollout is deterministic); accepted for the bench runner.
    """
    del repeats
    if len(models) != len(trajectories):
        raise InputError(
            f"suite.run.trajectories: give one trajectory per model ({len(models)} models, "
            f"{len(trajectories)} trajectories)"
        )
    names = ["original"] + [v for v in variants if v != "original"]
    rows, results, targets = [], {}, []
    for ckpt, source in zip(models, trajectories, strict=True):
        sim, _ = load_simulator(ckpt)
        truth = resolve_trajectory(source)
        most = available_steps(sim, truth)  # scored against the truth: never past its end
        run_steps = most if steps is None else min(int(steps), most)
        base = None
        for name in names:
            moved = variant(truth, name, seed)
            with torch.inference_mode():
                pred = rollout_trajectory(
                    sim, moved, steps=run_steps, progress=False, wall_guard=wall_guard
                )
            scalars = evaluate_pair(moved, pred).scalars
            row = {"model": ckpt, "trajectory": source, "variant": name}
            row |= {m: float(scalars.get(m, math.nan)) for m in METRICS}
            row["particles"] = int(truth.num_particles)
            rows.append(row)
            for m in METRICS:
                results[f"{ckpt}/{name}/{m}"] = row[m]
            if base is None:
                base = row
                continue
            targets += _targets(ckpt, name, row, base)
    for ckpt in models:
        for m in METRICS:
            values = [r[m] for r in rows if r["model"] == ckpt and np.isfinite(r[m])]
            if values:
                results[f"{ckpt}/spread/{m}"] = float(max(values) - min(values))
    notes = (
        f"Network {'with the wall guard' if wall_guard else 'alone'}; each variant scored "
        f"against its own transformed truth; turn_random seed {seed}."
    )
    return SuiteResult(rows, results, targets, _figure(rows, models), notes)


def _targets(ckpt: str, name: str, row: dict, base: dict) -> list[Target]:
    out = [
        Target(
            f"{ckpt} {name}: leaked - original's, % of particles",
            100.0 * (row["leaked_particles"] - base["leaked_particles"]) / row["particles"],
            "<=",
            0.5,
        )
    ]
    if np.isfinite(base["discharge_rate_rel_error"]):
        change = 100.0 * abs(row["discharge_rate_rel_error"] - base["discharge_rate_rel_error"])
        out.append(Target(f"{ckpt} {name}: |discharge error change|, pp", change, "<=", 3.0))
    if np.isfinite(base["angle_of_repose_error_deg"]):
        change = abs(row["angle_of_repose_error_deg"] - base["angle_of_repose_error_deg"])
        out.append(Target(f"{ckpt} {name}: |angle error change|, deg", change, "<=", 1.0))
    if base["emd_mean"] > 0:
        out.append(
            Target(
                f"{ckpt} {name}: EMD / original's", row["emd_mean"] / base["emd_mean"], "<=", 1.5
            )
        )
    return out


def _figure(rows: list[dict], models: tuple[str, ...]):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.2))
    for ckpt in models:
        mine = [r for r in rows if r["model"] == ckpt]
        labels = [r["variant"] for r in mine]
        axes[0].plot(labels, [r["leaked_particles"] for r in mine], "o-", label=ckpt)
        axes[1].plot(labels, [r["emd_mean"] for r in mine], "o-", label=ckpt)
    axes[0].set_ylabel("leaked particles")
    axes[1].set_ylabel("mean EMD (m^2)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.tick_params(axis="x", rotation=45)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
