"""Suite ``rest``: a settled bed that nothing disturbs must stay where it is.

Each model is rolled out (network alone unless ``wall_guard``) from the first frame of a
recorded trajectory held still (:func:`~granular_pyg.evaluation.variants.held_still`: every
velocity zero, the lid never removed, the drum never turning) for ``duration`` seconds. Reported
per (model, scene): the particles' mean drift from where they started, the centre of mass's
move, the largest drift, and the particles that leaked through a wall or left. Targets: mean
drift at most 0.3 mm, centre of mass at most 0.5 mm, no particle leaked.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from granular_pyg.bench.report import SuiteResult, Target
from granular_pyg.bench.trajectories import resolve_trajectory
from granular_pyg.errors import InputError
from granular_pyg.evaluation.variants import held_still
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.metrics import leaked_mask

#: Targets (m): a bed held still keeps its particles within these of where they started.
MEAN_DRIFT_M = 3e-4
CENTRE_OF_MASS_M = 5e-4


def run(
    models: tuple[str, ...],
    trajectories: tuple[str, ...],
    duration: float = 2.0,
    wall_guard: bool = False,
    repeats: int = 1,
) -> SuiteResult:
    """Run the suite (module docstring); ``trajectories[i]`` goes with ``models[i]`` (a file or
    ``sample:hopper`` / ``sample:drum``)."""
    del repeats
    if len(models) != len(trajectories):
        raise InputError(
            f"suite.run.trajectories: give one trajectory per model ({len(models)} models, "
            f"{len(trajectories)} trajectories)"
        )
    rows, results, targets, curves = [], {}, [], {}
    for ckpt, source in zip(models, trajectories, strict=True):
        sim, _ = load_simulator(ckpt)
        rest = held_still(resolve_trajectory(source), duration)
        with torch.inference_mode():
            pred = rollout_trajectory(sim, rest, progress=False, wall_guard=wall_guard)
        start = rest.positions[0].astype(np.float64)
        pos = pred.positions.astype(np.float64)
        drift = np.linalg.norm(pos - start, axis=2)  # [F, N], NaN once gone
        present = np.isfinite(pos[-1]).all(1)
        gone = int((~present).sum())
        com = (
            float(np.linalg.norm(pos[-1][present].mean(0) - start[present].mean(0)))
            if present.any()
            else float("nan")  # every particle left: drift and centre of mass are undefined
        )
        leaked_rows = leaked_mask(pos, rest.scene, pred.times).any(0)
        leaked = int(leaked_rows.sum())
        label = f"{ckpt} on {source}"
        row = {
            "model": ckpt,
            "trajectory": source,
            "particles": int(rest.num_particles),
            "seconds": float(pred.times[-1] - pred.times[0]),
            "mean_drift_mm": 1e3 * float(np.nanmean(drift[-1])) if present.any() else np.nan,
            "max_drift_mm": 1e3 * float(np.nanmax(drift[-1])) if present.any() else np.nan,
            "centre_of_mass_mm": 1e3 * com,
            "leaked": int(leaked),
            "left": gone,
        }
        rows.append(row)
        curves[label] = (pred.times - pred.times[0], 1e3 * np.nanmean(drift, axis=1))
        for key in ("mean_drift_mm", "max_drift_mm", "centre_of_mass_mm", "leaked", "left"):
            results[f"{label}/{key}"] = float(row[key])
        targets += [
            Target(f"{label}: mean drift, mm", row["mean_drift_mm"], "<=", 1e3 * MEAN_DRIFT_M),
            Target(
                f"{label}: centre of mass, mm",
                row["centre_of_mass_mm"],
                "<=",
                1e3 * CENTRE_OF_MASS_M,
            ),
            Target(f"{label}: leaked or left", float((leaked_rows | ~present).sum()), "<=", 0.0),
        ]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    for label, (t, d) in curves.items():
        ax.plot(t, d, label=label)
    ax.set_xlabel("time held still (s)")
    ax.set_ylabel("mean drift (mm)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    notes = f"Network {'with the wall guard' if wall_guard else 'alone'}, {duration} s held still."
    return SuiteResult(rows, results, targets, fig, notes)
