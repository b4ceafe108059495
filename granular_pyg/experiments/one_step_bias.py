"""One-step bias by height: does a model predict the right vertical acceleration on LIGGGHTS's
own states, band by band around a hopper's outlet?

Every ``every``-th learned step of each trajectory (up to ``last_time``), the model sees the
ground-truth window (no noise, no rollout) and predicts the acceleration of each particle
present throughout; the table holds, per height band of the last position (m, relative to the
outlet), the mean predicted and true vertical acceleration (m/s^2), their difference (the
bias) and the RMS error; with time bands, one row per (height band, time band), times counted
from the moment the outlet opens (the scene's first wall removal, e.g. the lid), so that the
bed's response to the opening stands apart from the steady discharge. A model that is unbiased
here but whose rollouts still drift off learns from LIGGGHTS's states only and errs on its
own: the case for push-forward training (README, Reproducing the paper).

``python -m granular_pyg.experiments.one_step_bias ckpt=<run>/checkpoints/last.ckpt
'files=[data/paper_hopper/traj_0033.h5]'`` (config ``conf/one_step_bias.yaml``) prints the
table and writes ``table.md`` and ``results.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from granular_pyg.cli import command
from granular_pyg.data.windows import WindowDataset
from granular_pyg.errors import InputError
from granular_pyg.inference import frames_per_step, load_simulator
from granular_pyg.io import (
    Trajectory,
    atomic_write,
    command_header,
    command_line,
    markdown_table,
    read_trajectory,
)
from granular_pyg.simulator import LearnedSimulator

__all__ = ["format_table", "one_step_bias"]


def _opening_time(traj: Trajectory, name: str) -> float:
    """Time (s) the outlet of ``traj`` (called ``name`` in errors) opens: its first wall
    removal."""
    opens = traj.scene.opening_time if traj.scene is not None else None
    if opens is None:
        raise InputError(
            f"times: {name} has no wall removed (no lid), so no time the outlet opens to count "
            "from; leave it out, or drop times="
        )
    return opens


def one_step_bias(
    sim: LearnedSimulator,
    trajectories: list[Trajectory],
    bands: list[tuple[float, float]],
    every: int = 1,
    last_time: float | None = None,
    times: list[tuple[float, float]] | None = None,
) -> list[dict]:
    """Mean predicted against true vertical acceleration per height band (see the module).

    Args:
        sim: a trained simulator; its ``dt`` sets the time-step multiple ``k``.
        trajectories: LIGGGHTS trajectories with their Scene.
        bands: ``(z_low, z_high)`` (m above the outlet, ``params['outlet_z']``, 0 if unset) of
            each band; a particle counts in every band that holds its last position.
        every: use every ``every``-th learned step's window.
        last_time: latest time (s) of a window's last position; None: to the end.
        times: ``(t_low, t_high)`` (s after the outlet opens) of each time band, a window
            counting in every band that holds the time of its last position; None: one band
            over all times.

    Returns:
        One row per (band, time band), heights outer: ``z_low``, ``z_high``, ``t_low``,
        ``t_high`` (s; None without time bands), ``count`` (particle-windows), ``pred_az``,
        ``true_az``, ``bias`` (pred - true) and ``rmse`` (m/s^2; NaN if empty).
    """
    if not bands or any(not lo < hi for lo, hi in bands):
        raise InputError(f"bands: expected (z_low, z_high) pairs with z_low < z_high, got {bands}")
    if times is not None and (not times or any(not lo < hi for lo, hi in times)):
        raise InputError(
            f"times: expected (t_low, t_high) pairs (s after the outlet opens) with t_low < "
            f"t_high, got {times}"
        )
    if every < 1:
        raise InputError(f"every: expected a positive stride, got {every}")
    spans = [(None, None)] if times is None else list(times)
    cells = [(b, s) for b in bands for s in spans]
    pred_in = [[] for _ in cells]
    true_in = [[] for _ in cells]
    for i, traj in enumerate(trajectories):
        opens = 0.0 if times is None else _opening_time(traj, f"trajectory {i}")
        k = frames_per_step(sim, traj.frame_dt)
        windows = WindowDataset([traj], sim.history, k)  # every frame's window; keep each k-th
        outlet_z = float(traj.scene.params.get("outlet_z", 0.0))
        for item, (_, t) in enumerate(windows.index):
            if last_time is not None and traj.times[t] > last_time:
                break
            if (t - sim.history * k) % (every * k):
                continue
            window = windows[item]
            seq = window.pos_seq
            with torch.no_grad():
                pred = sim.predict_acceleration(seq, window.walls, window.time, props=window.props)
                pred = pred[:, 2]
                true = sim.target_acceleration(seq, window.target_pos).double()
            true = (true * sim.acc_std.double() + sim.acc_mean.double())[:, 2]
            z = seq[:, -1, 2].double().numpy() - outlet_z
            pred_z, true_z = pred.double().numpy(), true.numpy()
            since = float(traj.times[t]) - opens
            for c, ((lo, hi), (t_lo, t_hi)) in enumerate(cells):
                if t_lo is not None and not t_lo <= since < t_hi:
                    continue
                inside = (z >= lo) & (z < hi)
                pred_in[c].append(pred_z[inside])
                true_in[c].append(true_z[inside])
    rows = []
    for ((lo, hi), (t_lo, t_hi)), p, q in zip(cells, pred_in, true_in, strict=True):
        p = np.concatenate(p) if p else np.empty(0)
        q = np.concatenate(q) if q else np.empty(0)
        n = int(p.size)
        mean = (lambda a: float(a.mean())) if n else (lambda a: float("nan"))
        rows.append(
            {
                "z_low": lo,
                "z_high": hi,
                "t_low": t_lo,
                "t_high": t_hi,
                "count": n,
                "pred_az": mean(p),
                "true_az": mean(q),
                "bias": mean(p - q),
                "rmse": float(np.sqrt(np.mean((p - q) ** 2))) if n else float("nan"),
            }
        )
    return rows


def format_table(rows: list[dict]) -> str:
    """Markdown table of :func:`one_step_bias`'s rows (heights in mm; a time column when the
    rows have time bands)."""
    timed = any(r.get("t_low") is not None for r in rows)
    columns = [
        "height above the outlet (mm)",
        *(["after the outlet opens (s)"] if timed else []),
        "particle-windows",
        "predicted a_z",
        "LIGGGHTS a_z",
        "bias",
        "RMS error",
    ]
    cells = [
        [
            f"{1e3 * r['z_low']:g} to {1e3 * r['z_high']:g}",
            *([f"{r['t_low']:g} to {r['t_high']:g}"] if timed else []),
            f"{r['count']}",
            f"{r['pred_az']:.2f}",
            f"{r['true_az']:.2f}",
            f"{r['bias']:+.2f}",
            f"{r['rmse']:.2f}",
        ]
        for r in rows
    ]
    table = markdown_table(columns, cells, align="l" + "l" * timed + "rrrrr")
    return table + "\n\n(m/s^2; z up, gravity -9.81)\n"


@command("one_step_bias")
def main(cfg: DictConfig) -> None:
    torch.set_num_threads(cfg.threads)
    sim, _ = load_simulator(cfg.ckpt)
    sim.eval()
    trajectories = [read_trajectory(f) for f in cfg.files]
    bands = [(float(lo), float(hi)) for lo, hi in cfg.bands]
    times = None if cfg.times is None else [(float(lo), float(hi)) for lo, hi in cfg.times]
    rows = one_step_bias(sim, trajectories, bands, cfg.every, cfg.last_time, times)
    module = "granular_pyg.experiments.one_step_bias"
    table = format_table(rows)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "table.md") as fh:
        fh.write(f"{command_header(module)}\n\n{table}")
    with atomic_write(out / "results.json") as fh:
        json.dump({"command": command_line(module), "rows": rows}, fh, indent=1)
    print(table)
    print(f"output: {out}")


if __name__ == "__main__":
    main()
