"""``python -m granular_pyg.evaluate ckpt=...``: rollouts on held-out trajectories, metrics
(CSV, JSON), figures (PNG) and a Markdown report, also in TensorBoard.

The folder it writes (``outputs/evaluate/<time>/``) is what ``python -m granular_pyg.compare``
reads to build the paper's variant table.
"""

from __future__ import annotations

import dataclasses
import glob
import sys
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from granular_pyg.checkpoint.model import processor_name
from granular_pyg.cli import command
from granular_pyg.data import load_split
from granular_pyg.errors import InputError, flag, whole_number
from granular_pyg.evaluation import evaluate_pair, write_evaluation
from granular_pyg.evaluation.compare import VARIANTS
from granular_pyg.evaluation.report import EvaluatedRollout, distinct_names, rollout_label
from granular_pyg.inference import (
    available_steps,
    frames_per_step,
    load_simulator,
    matching_frames,
    rollout_trajectory,
    warn_outside_training,
)
from granular_pyg.io import (
    Trajectory,
    check_output,
    export_paraview,
    read_trajectory,
    write_trajectory,
)
from granular_pyg.scene_start import recorded_part, scene_start, whole_job_scalars

__all__ = ["evaluate", "selected_files"]

#: Scalars printed to the console (the report has them all).
CONSOLE = (
    "emd_mean",
    "discharge_rate_rel_error",
    "discharged_fraction_error",
    "angle_of_repose_error_deg",
    "leaked_particles",
    "rollout_wall_s",
)


def evaluate(cfg: DictConfig) -> Path:
    """Evaluate as ``cfg`` says; returns the path of the Markdown report."""
    torch.set_num_threads(cfg.threads)
    check_output(Path(cfg.out) / "report.md", overwrite=cfg.get("overwrite", False))
    sim, config = load_simulator(cfg.ckpt)
    data = config.get("data", {})
    root = cfg.root if cfg.root or cfg.sample else data.get("root")
    sample = cfg.sample if cfg.root or cfg.sample else data.get("sample")
    if root is None and sample is None and not cfg.get("trajectories"):
        raise InputError(
            f"root: {cfg.ckpt} records no training data to evaluate on; pass root=<dataset "
            "folder>, sample=hopper (or drum), or trajectories=[<file.h5>]"
        )
    out = Path(cfg.out)
    rollouts = []
    selected = {
        split: files[: cfg.max_trajectories]
        for split, files in selected_files(cfg, root, sample).items()
    }
    every = [file for files in selected.values() for file in files]
    start_frame = whole_number("start_frame", cfg.get("start_frame", 0))
    from_scene = flag("from_scene", cfg.get("from_scene", False))
    names = dict(zip(every, distinct_names(every), strict=True))  # families share file names
    for split, files in selected.items():
        for file in files:
            label = rollout_label(split, names[file])
            truth = read_trajectory(file)
            warn_outside_training(config, truth, str(file))
            options = {
                "progress": cfg.progress,
                "skin": cfg.skin,
                "wall_guard": cfg.wall_guard,
                "precision": str(cfg.get("precision", "32")),
            }
            start = time.perf_counter()
            if from_scene:  # the whole job: fill, settle and discharge, network alone
                whole = _rollout_from_scene(sim, truth, options)
                wall = time.perf_counter() - start
                pred = recorded_part(whole, truth)
            else:
                pred = rollout_trajectory(
                    sim,
                    truth,
                    _steps_within(cfg.steps, sim, truth, str(file), start_frame),
                    start_frame=start_frame,
                    **options,
                )
                wall = time.perf_counter() - start
            pred_file = out / "rollouts" / f"{label}.h5"
            pred.metadata |= {"ckpt": str(cfg.ckpt), "truth_file": str(file)}
            write_trajectory(pred, pred_file)
            if from_scene:  # the fill and settle too
                whole.metadata |= {"ckpt": str(cfg.ckpt), "truth_file": str(file)}
                write_trajectory(whole, out / "rollouts" / f"{label}_whole_job.h5")
            evaluation = evaluate_pair(truth, pred)
            # The learned rollout alone (graphs, network, integration, outflow, guard), not
            # the file writing or the metrics.
            evaluation.scalars["rollout_wall_s"] = wall
            first = int(pred.metadata.get("initial_frames", 1)) - 1
            evaluation.scalars["rollout_simulated_s"] = float(pred.times[-1] - pred.times[first])
            if from_scene:
                whole_job_scalars(evaluation.scalars, whole)
            if cfg.wall_guard:  # how often the guard stepped in: the network's own leaks
                corrections = float(pred.metadata["wall_guard_corrections"])
                evaluation.scalars["wall_guard_corrections"] = corrections
            if len(rollouts) < cfg.paraview:
                pvd = export_paraview(
                    out / "paraview" / label,
                    {"truth": _at_rollout_frames(truth, pred), "prediction": pred},
                    every=cfg.paraview_every,
                    progress=cfg.progress,
                )
                print(f"ParaView: {pvd}")
            rollouts.append(
                EvaluatedRollout(split, names[file], str(file), str(pred_file), evaluation)
            )
    info = {
        "variant": VARIANTS.get(
            config["model"].get("normals"), str(config["model"].get("normals"))
        ),
        "ckpt": str(cfg.ckpt),
        "seed": config.get("seed"),
        "processor": processor_name(config["model"]),
        "data": {"root": root, "sample": sample},
        "command": _command(cfg),
        "threads": int(torch.get_num_threads()),
        "from_scene": bool(from_scene),
        "device": "cpu",
    }
    report = write_evaluation(out, rollouts, info)
    for split, values in _split_means(rollouts).items():
        shown = ", ".join(f"{k} {v:.3g}" for k, v in values.items())
        print(f"{split}: {shown}")
    print(f"report: {report}")
    return report


def _rollout_from_scene(sim, truth: Trajectory, options: dict) -> Trajectory:
    """A rollout of ``sim`` from ``truth``'s Scene alone (packed at rest at the start of the
    fill, seeded by the truth's LIGGGHTS seed) to ``truth``'s last recorded time."""
    k = frames_per_step(sim, float(truth.frame_dt))
    start = scene_start(truth.scene, sim.history, k, seed=int(truth.metadata.get("seed", 0)))
    if start.num_particles != truth.num_particles:
        raise InputError(
            f"from_scene: the scene inserts {start.num_particles} particles, its LIGGGHTS run "
            f"holds {truth.num_particles}; evaluate from_scene only on complete fills"
        )
    steps = round((float(truth.times[-1]) - float(start.times[-1])) / float(sim.dt))
    return rollout_trajectory(sim, start, steps, name="the scene's packing", **options)


def _steps_within(
    steps: int | None, sim, truth: Trajectory, name: str, start_frame: int = 0
) -> int | None:
    """``steps``, or the learned steps ``truth`` has frames for where it asks for more (with a
    warning): a rollout past the ground truth's end has nothing to be compared with."""
    available = available_steps(sim, truth, start_frame)
    if steps is not None and int(steps) > available:
        print(
            f"warning: {name}: steps={steps} runs past its last frame; evaluating the "
            f"{available} learned steps it has frames for",
            file=sys.stderr,
        )
        return available
    return steps


def selected_files(cfg: DictConfig, root: str | None, sample: str | None) -> dict[str, list[Path]]:
    """The trajectories to evaluate, by split: ``cfg.trajectories`` (HDF5 files or glob
    patterns, under the label ``files``) when given, else ``cfg.splits`` of the dataset folder
    ``root`` (its ``manifest.json``) or of the bundled ``sample``.

    Raises:
        InputError: a pattern that matches no file, or ``root`` naming a file, not a folder.
    """
    if cfg.get("trajectories"):
        patterns = cfg.trajectories
        patterns = [patterns] if isinstance(patterns, str) else list(patterns)
        files = []
        for pattern in map(str, patterns):
            found = sorted(Path(p) for p in glob.glob(pattern))
            if not found:
                raise InputError(f"trajectories: {pattern!r} matches no file")
            files += [f for f in found if f not in files]
        return {"files": files}
    if root is not None and Path(root).is_file():
        raise InputError(
            f"root: {root} is a file; root is a dataset folder with a manifest.json "
            f"(docs/data.md). For single files: trajectories='[{root}]'"
        )
    return {split: load_split(root, sample, split) for split in cfg.splits}


def _command(cfg: DictConfig) -> str:
    """The command line that reproduces this evaluation (also when called from Python)."""
    parts = [f"ckpt={cfg.ckpt}"]
    if cfg.get("trajectories"):
        listed = [cfg.trajectories] if isinstance(cfg.trajectories, str) else cfg.trajectories
        parts.append(f"'trajectories=[{','.join(map(str, listed))}]'")
    else:
        parts.append(f"splits=[{','.join(cfg.splits)}]")
    for key in ("root", "sample", "max_trajectories", "steps", "skin"):
        if cfg[key] is not None:
            parts.append(f"{key}={cfg[key]}")
    if cfg.wall_guard:
        parts.append("wall_guard=true")
    if cfg.get("from_scene"):
        parts.append("from_scene=true")
    return "python -m granular_pyg.evaluate " + " ".join(parts)


def _at_rollout_frames(truth: Trajectory, pred: Trajectory) -> Trajectory:
    """``truth`` at the frames of ``pred`` (every k-th), for a frame-by-frame ParaView view."""
    idx = matching_frames(truth, pred)
    return dataclasses.replace(
        truth, positions=truth.positions[idx], velocities=truth.velocities[idx], times=pred.times
    )


def _split_means(rollouts: list[EvaluatedRollout]) -> dict[str, dict[str, float]]:
    """Means per split of the scalars shown on the console."""
    values: dict[str, dict[str, list[float]]] = {}
    for r in rollouts:
        for key in CONSOLE:
            if key in r.evaluation.scalars:
                values.setdefault(r.split, {}).setdefault(key, []).append(r.evaluation.scalars[key])
    return {s: {k: float(np.nanmean(v)) for k, v in row.items()} for s, row in values.items()}


@command("evaluate")
def main(cfg: DictConfig) -> None:
    evaluate(cfg)


if __name__ == "__main__":
    main()
