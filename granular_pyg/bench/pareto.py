"""Suite ``pareto``: rollout error against wall time per simulated second, across settings.

Every checkpoint (a model size, processor, time-step multiple k, radius: whatever it was
trained with) is rolled out over the Scenes of ground-truth test trajectories, on this machine,
one after the other. Per checkpoint, summed or averaged over the trajectories:

- wall time per simulated second of the learned rollout (graphs, forward passes, integration,
  outflow; the copied initial frames are not simulated time);
- EMD (W2^2, m^2) at fixed simulated horizons after the last initial frame, the same times for
  every k (a horizon past a rollout's end, or where the truth has drained, is left out);
- hopper discharge-rate error and leaked particles over the whole rollout.

A setting is on the front of an error measure when no other one is both at least as fast and
at least as accurate (and better in one). LIGGGHTS's serial wall time per simulated second on
the same Scenes (run again here; its fill-and-settle run left out) is drawn for reference.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from granular_pyg import metrics
from granular_pyg.bench.liggghts import rerun_liggghts
from granular_pyg.bench.report import SuiteResult
from granular_pyg.checkpoint.model import processor_name
from granular_pyg.errors import InputError
from granular_pyg.evaluation import evaluate_pair
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.io import Trajectory, read_trajectory
from granular_pyg.pretrained import PREFIX
from granular_pyg.samples import sample_files

#: Error measures with a front of their own: (row key, axis label).
MEASURES = (
    ("emd_at_0.1s", "EMD at 0.1 s (m$^2$)"),
    ("discharge_rate_rel_error", "discharge-rate error"),
)


def emd_at_horizons(
    truth: Trajectory, pred: Trajectory, horizons_s: tuple[float, ...]
) -> dict[float, float]:
    """``{horizon (s): EMD (m^2)}`` between ``pred`` and ``truth`` at the predicted frame
    nearest each time ``horizon`` after ``pred``'s last initial frame (within half a frame of
    ``truth``). Horizons past the rollout are left out; where one set is empty, the other's
    particles are moved to the outlet (:func:`granular_pyg.metrics.outlet_point`), so a model
    that drains too fast is not rewarded."""
    start = pred.times[int(pred.metadata.get("initial_frames", 1)) - 1]
    sink = metrics.outlet_point(truth.scene) if truth.scene is not None else None
    out = {}
    for h in horizons_s:
        i = int(np.argmin(np.abs(pred.times - (start + h))))
        j = int(np.argmin(np.abs(truth.times - pred.times[i])))
        if abs(pred.times[i] - (start + h)) > 0.5 * (pred.times[1] - pred.times[0]):
            continue
        out[h] = metrics.emd(truth.positions[j], pred.positions[i], sink=sink)
    return out


def pareto_front(speed: list[float], error: list[float]) -> list[bool]:
    """Which points are on the front of ``(speed, error)``, both lower-is-better: no other
    point is at most as large in both and smaller in one. NaN points are never on it."""
    on = []
    for i, (s, e) in enumerate(zip(speed, error, strict=True)):
        if math.isnan(s) or math.isnan(e):
            on.append(False)
            continue
        dominated = any(
            s2 <= s and e2 <= e and (s2 < s or e2 < e)
            for j, (s2, e2) in enumerate(zip(speed, error, strict=True))
            if j != i and not (math.isnan(s2) or math.isnan(e2))
        )
        on.append(not dominated)
    return on


def _label(ckpt: str, config: dict, k: int) -> str:
    model = config["model"]
    run_dir = Path(ckpt).parent.parent  # <run>/checkpoints/<name>.ckpt
    name = "/".join(run_dir.parts[1:]) if run_dir.parts[:1] == ("outputs",) else run_dir.name
    if str(ckpt).startswith(PREFIX):
        name = "pretrained/" + str(ckpt)[len(PREFIX) :]
    return (
        f"{name}: {processor_name(model)}, latent "
        f"{model['latent']}, R {1e3 * model['radius']:g} mm, k {k}"
    )


def run(
    ckpts: tuple[str, ...],
    trajectories: tuple[str, ...] | None = None,
    horizons_s: tuple[float, ...] = (0.05, 0.1, 0.2),
    threads: int = 2,
    liggghts: bool = True,
    repeats: int = 1,
) -> SuiteResult:
    """Run the suite; see the module docstring. ``repeats`` is unused (one rollout each).

    Args:
        ckpts: checkpoints to compare (``outputs/<run>/checkpoints/last.ckpt``).
        trajectories: ground-truth trajectories; None: the bundled hopper test ones.
        horizons_s: simulated times after the initial frames at which EMD is taken (s).
        threads: torch threads of the rollouts.
        liggghts: also run LIGGGHTS serially on the same Scenes, for reference.
    """
    if not ckpts:
        raise InputError("suite.run.ckpts: empty; list the checkpoints to compare")
    torch.set_num_threads(threads)
    truths = [read_trajectory(p) for p in (trajectories or sample_files("hopper", "test"))]
    rows = []
    for ckpt in ckpts:
        sim, config = load_simulator(ckpt)
        wall = simulated = 0.0
        emds: dict[float, list[float]] = {h: [] for h in horizons_s}
        discharge, leaked = [], 0.0
        with torch.inference_mode():
            rollout_trajectory(sim, truths[0], steps=2, progress=False)  # warm-up
            for truth in truths:
                start = time.perf_counter()
                pred = rollout_trajectory(sim, truth, progress=False)
                wall += time.perf_counter() - start
                simulated += pred.metadata["steps"] * pred.metadata["dt"]
                for h, value in emd_at_horizons(truth, pred, horizons_s).items():
                    emds[h].append(value)
                scalars = evaluate_pair(truth, pred).scalars
                discharge.append(scalars.get("discharge_rate_rel_error", float("nan")))
                leaked += scalars["leaked_particles"]
        k = int(pred.metadata["frames_per_step"])
        model = config["model"]
        rows.append(
            {
                "setting": _label(ckpt, config, k),
                "ckpt": ckpt,
                "processor": processor_name(model),
                "latent": model["latent"],
                "radius_m": model["radius"],
                "k": k,
                "parameters": sum(p.numel() for p in sim.parameters()),
                "wall_s_per_simulated_s": wall / simulated,
                **{f"emd_at_{h:g}s": float(np.mean(v)) if v else math.nan for h, v in emds.items()},
                "discharge_rate_rel_error": float(np.nanmean(discharge))
                if np.isfinite(discharge).any()
                else math.nan,
                "leaked_particles": leaked,
            }
        )
    speed = [r["wall_s_per_simulated_s"] for r in rows]
    for key, _ in MEASURES:
        front = pareto_front(speed, [r.get(key, math.nan) for r in rows])
        for row, on in zip(rows, front, strict=True):
            row[f"front_{key}"] = on
    reference = math.nan
    if liggghts:
        loops = [rerun_liggghts(t, 1)[0] for t in truths]
        span = sum(float(t.times[-1] - t.times[0]) for t in truths)
        reference = sum(loops) / span
        rows.append({"setting": "LIGGGHTS, serial", "wall_s_per_simulated_s": reference})
    results = {f"{r['setting']}/wall_s_per_simulated_s": r["wall_s_per_simulated_s"] for r in rows}
    for key, _ in MEASURES:
        front = [r for r in rows if r.get(f"front_{key}")]
        results[f"front_size/{key}"] = float(len(front))
    notes = _notes(rows, truths, horizons_s, threads)
    return SuiteResult(rows, results, [], _figure(rows, reference), notes)


def _notes(rows: list[dict], truths: list[Trajectory], horizons_s, threads: int) -> str:
    lines = [
        f"{len(truths)} test trajectories ({', '.join(str(t.num_particles) for t in truths)} "
        f"particles); EMD at {', '.join(f'{h:g}' for h in horizons_s)} s after the initial "
        f"frames; {threads} torch threads.",
        "",
        "Settings on the front (no other setting both faster and more accurate):",
        "",
    ]
    for key, label in MEASURES:
        front = sorted(
            (r for r in rows if r.get(f"front_{key}")), key=lambda r: r["wall_s_per_simulated_s"]
        )
        names = "; ".join(
            f"{r['setting']} ({r['wall_s_per_simulated_s']:.3g} s/s, {r[key]:.3g})" for r in front
        )
        lines.append(f"- {label.replace('$^2$', '²')}: {names or 'none'}")
    return "\n".join(lines)


def _figure(rows: list[dict], reference: float):
    learned = [r for r in rows if "k" in r]
    fig, axes = plt.subplots(1, len(MEASURES), figsize=(6 * len(MEASURES), 4.2))
    for ax, (key, label) in zip(axes, MEASURES, strict=True):
        for r in learned:
            on = r.get(f"front_{key}")
            ax.scatter(
                r["wall_s_per_simulated_s"],
                r[key],
                marker="o" if on else "x",
                s=50,
                color="C3" if on else "C0",
            )
            ax.annotate(
                r["setting"].split(":")[0], (r["wall_s_per_simulated_s"], r[key]), fontsize=7
            )
        front = sorted(
            (r for r in learned if r.get(f"front_{key}")),
            key=lambda r: r["wall_s_per_simulated_s"],
        )
        if front:
            ax.step(
                [r["wall_s_per_simulated_s"] for r in front],
                [r[key] for r in front],
                where="post",
                color="C3",
                lw=1,
                label="front",
            )
        if math.isfinite(reference):
            ax.axvline(reference, color="k", ls="--", lw=1, label="LIGGGHTS serial")
        ax.set_xscale("log")
        if key.startswith("emd"):
            ax.set_yscale("log")
        ax.set_xlabel("wall s per simulated s")
        ax.set_ylabel(label)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
