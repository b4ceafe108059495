"""Suite ``rollout_speed``: wall time of learned rollouts per simulated second, on any device.

Each checkpoint is rolled out over the Scene of a ground-truth trajectory (default: the first
bundled hopper test trajectory) to its end, after a short warm-up rollout, on ``device``
(``cpu`` or ``cuda``), with CUDA synchronised before the clock stops. Comparable with the
``liggghts`` suite's LIGGGHTS figures for the same Scene.
"""

from __future__ import annotations

import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from granular_pyg.bench.report import SuiteResult, synchronize
from granular_pyg.checkpoint.model import processor_name
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files


def run(
    ckpts: tuple[str, ...],
    trajectory: str | None = None,
    device: str = "cpu",
    threads: int = 2,
    repeats: int = 1,
) -> SuiteResult:
    """Run the suite; see the module docstring. The median of ``repeats`` rollouts is kept."""
    torch.set_num_threads(threads)
    truth = read_trajectory(trajectory or sample_files("hopper", "test")[0])
    rows, results = [], {}
    for ckpt in ckpts:
        sim, config = load_simulator(ckpt, map_location=device)
        with torch.inference_mode():
            rollout_trajectory(sim, truth, steps=3, progress=False)  # warm-up
            times = []
            for _ in range(max(1, repeats)):
                synchronize(device)
                start = time.perf_counter()
                pred = rollout_trajectory(sim, truth, progress=False)
                synchronize(device)
                times.append(time.perf_counter() - start)
        wall = sorted(times)[len(times) // 2]
        steps = pred.metadata["steps"]
        simulated = steps * pred.metadata["dt"]
        model = config["model"]
        rows.append(
            {
                "ckpt": ckpt,
                "device": torch.cuda.get_device_name(0) if device.startswith("cuda") else "cpu",
                "processor": processor_name(model),
                "latent": model["latent"],
                "k": pred.metadata["frames_per_step"],
                "steps": steps,
                "simulated_s": simulated,
                "wall_s": wall,
                "ms_per_step": 1e3 * wall / steps,
                "wall_s_per_simulated_s": wall / simulated,
            }
        )
        results[f"rollout/{ckpt}/{device}/s_per_simulated_s"] = wall / simulated
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh(
        [f"{r['ckpt']} (k={r['k']})" for r in rows], [r["wall_s_per_simulated_s"] for r in rows]
    )
    ax.set_xlabel(f"wall s per simulated s ({device})")
    fig.tight_layout()
    notes = f"{truth.num_particles} particles, device {device}, {threads} CPU threads."
    return SuiteResult(rows, results, [], fig, notes)
