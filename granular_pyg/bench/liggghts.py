"""Suite ``liggghts``: LIGGGHTS against the learned rollout on the same Scene, side by side.

The Scene of a ground-truth trajectory (default: the first bundled hopper test trajectory) is
run again by LIGGGHTS, serial and with MPI, and rolled out by a trained model from the same
initial states, on the same machine. Compared per simulated second of the recorded phase:
LIGGGHTS's own ``Loop time`` of the recorded runs (the fill-and-settle run before recording is
left out; writing the dump is in, as in any real run) against the wall time of the learned
rollout (graphs, forward passes, integration, outflow). The rollout's accuracy against the
ground truth is reported with it: discharge-rate error, EMD, leaked particles. With
``device=cuda`` the learned rollout runs on the GPU (after a short warm-up rollout), and a third
target compares it with LIGGGHTS on all the machine's cores (the largest ``mpi_procs``). The
targets: at least 20x serial LIGGGHTS on one core each, within 10% of the discharge rate; on a
GPU at least 100x LIGGGHTS on all cores.
"""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from granular_pyg.bench.report import SuiteResult, Target, synchronize
from granular_pyg.dem import DemRun
from granular_pyg.dem.simulate import simulate
from granular_pyg.errors import InputError
from granular_pyg.evaluation import evaluate_pair
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.io import Trajectory, read_trajectory
from granular_pyg.samples import sample_files

#: Targets: the learned rollout against serial LIGGGHTS (on a GPU: against LIGGGHTS on all
#: cores), as speed-ups; the discharge-rate error of that rollout.
SPEEDUP_OVER_SERIAL = 20.0
GPU_SPEEDUP_OVER_ALL_CORES = 100.0
MAX_DISCHARGE_ERROR = 0.1

LOOP_TIME = re.compile(r"^Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps", re.M)


def recorded_loop_time(log: Path) -> float:
    """Seconds LIGGGHTS spent in the runs after the first (the fill-and-settle run)."""
    loops = [float(m.group(1)) for m in LOOP_TIME.finditer(log.read_text())]
    if len(loops) < 2:
        raise InputError(f"{log}: expected a settle run and recorded runs, found {len(loops)}")
    return sum(loops[1:])


def rerun_liggghts(truth: Trajectory, mpi_procs: int = 1) -> tuple[float, DemRun]:
    """Run the Scene and seed of ``truth`` again with LIGGGHTS on ``mpi_procs`` processes.

    Returns:
        ``(recorded_s, result)``: LIGGGHTS's loop time of the recorded phase (s, the
        fill-and-settle run left out) and the run's :class:`DemRun`.
    """
    seed = int(truth.metadata.get("seed", 0))
    with tempfile.TemporaryDirectory(prefix="bench_liggghts_") as tmp:
        _, dem = simulate(
            truth.scene, seed, tmp, keep_workdir=True, mpi_procs=mpi_procs, progress=False
        )
        return recorded_loop_time(Path(tmp) / "log.liggghts"), dem


def run(
    ckpt: str,
    trajectory: str | None = None,
    mpi_procs: tuple[int, ...] = (1, 2),
    threads: int = 2,
    skin: float | None = None,
    wall_guard: bool = False,
    device: str = "cpu",
    repeats: int = 1,
    precisions: tuple[str, ...] = ("32",),
) -> SuiteResult:
    """Run the suite; see the module docstring. With ``wall_guard`` the learned rollout is
    also timed with the wall guard (a second row); each of ``precisions`` (the network's, see
    ``LearnedSimulator.set_network_precision``) gets its rows, and the targets are those of the
    last precision's unguarded rollout. ``repeats`` is unused (one run each)."""
    truth = read_trajectory(trajectory or sample_files("hopper", "test")[0])
    scene = truth.scene
    simulated = float(truth.times[-1] - truth.times[0])
    rows, results = [], {}
    for procs in mpi_procs:
        loop, dem = rerun_liggghts(truth, procs)
        rows.append(
            {
                "simulator": f"LIGGGHTS, {procs} MPI process{'es' if procs > 1 else ''}",
                "simulated_s": simulated,
                "wall_s": loop,
                "wall_s_per_simulated_s": loop / simulated,
                "whole_run_s": dem.wall_time_s,
            }
        )
    torch.set_num_threads(threads)
    sim, config = load_simulator(ckpt, map_location=device)
    model = config["model"]
    if device != "cpu":
        with torch.inference_mode():
            rollout_trajectory(sim, truth, steps=3, progress=False)  # kernels, allocator
    runs = [
        (p, g) for p in map(str, precisions) for g in ((False, True) if wall_guard else (False,))
    ]
    for precision, guarded in runs:
        with torch.inference_mode():
            synchronize(device)
            start = time.perf_counter()
            pred = rollout_trajectory(
                sim, truth, progress=False, skin=skin, wall_guard=guarded, precision=precision
            )
            synchronize(device)
            wall = time.perf_counter() - start
        scalars = evaluate_pair(truth, pred).scalars
        learned_sim = float(pred.times[-1] - pred.times[pred.metadata["initial_frames"] - 1])
        rows.append(
            {
                "simulator": f"learned ({model.get('normals')}, {model['processor']['layer']}, "
                f"latent {model['latent']}, k = {pred.metadata['time_step_multiple']}"
                + (f", {device}" if device != "cpu" else "")
                + (", bf16" if precision == "bf16" else "")
                + (", wall guard)" if guarded else ")"),
                "simulated_s": learned_sim,
                "wall_s": wall,
                "wall_s_per_simulated_s": wall / learned_sim,
                "parameters": sum(p.numel() for p in sim.parameters()),
                "discharge_rate_rel_error": scalars.get("discharge_rate_rel_error", float("nan")),
                "emd_mean": scalars["emd_mean"],
                "leaked_particles": scalars["leaked_particles"],
            }
        )
    if wall_guard:  # the targets are the model's own rollout's
        rows.append(rows.pop(-2))
    serial = rows[0]["wall_s_per_simulated_s"]
    learned = rows[-1]["wall_s_per_simulated_s"]
    results = {
        "liggghts_serial_s_per_simulated_s": serial,
        "learned_s_per_simulated_s": learned,
        "learned_speedup_over_serial": serial / learned,
        "discharge_rate_rel_error": rows[-1]["discharge_rate_rel_error"],
    }
    targets = [
        Target(
            "learned rollout speed / serial LIGGGHTS", serial / learned, ">=", SPEEDUP_OVER_SERIAL
        ),
        Target(
            "discharge-rate error of that rollout",
            rows[-1]["discharge_rate_rel_error"],
            "<=",
            MAX_DISCHARGE_ERROR,
        ),
    ]
    if device != "cpu":
        procs = max(mpi_procs)
        all_cores = rows[list(mpi_procs).index(procs)]["wall_s_per_simulated_s"]
        results["learned_speedup_over_liggghts_all_cores"] = all_cores / learned
        targets.append(
            Target(
                f"learned rollout on {device} / LIGGGHTS on all cores ({procs} MPI processes)",
                all_cores / learned,
                ">=",
                GPU_SPEEDUP_OVER_ALL_CORES,
            )
        )
    notes = (
        f"Scene of `{Path(trajectory or sample_files('hopper', 'test')[0]).name}` "
        f"({truth.num_particles} particles, {simulated:g} s recorded, frames every "
        f"{truth.frame_dt * 1e3:g} ms, DEM dt {scene.dem_dt:g} s); model `{ckpt}`; "
        f"{threads} torch threads, learned rollout on {device}."
    )
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh([r["simulator"] for r in rows], [r["wall_s_per_simulated_s"] for r in rows])
    ax.set_xlabel("wall s per simulated s")
    fig.tight_layout()
    return SuiteResult(rows, results, targets, fig, notes)
