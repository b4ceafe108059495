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

The whole job (``whole_job``, on by default): LIGGGHTS's fill, settle and recorded runs (all
its loop times) against the learned rollout from the Scene alone (particles packed at rest in
the insertion region, :mod:`granular_pyg.scene_start`) over the same time, with its discharge
against LIGGGHTS's recording: rate error, discharged fraction, leaked particles (targets: 20x,
10%, 2 points, 0.5%). ``scene=`` (a shipped scene's name or the user's scene YAML) and
``num_particles=`` (the scene scaled to hold that many, :func:`scaled_build`) run LIGGGHTS on
that Scene first and take its recording as the ground truth.
"""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path

import hydra
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from granular_pyg.bench.report import SuiteResult, Target, synchronize
from granular_pyg.checkpoint.model import processor_name
from granular_pyg.dem import DemRun
from granular_pyg.dem.simulate import simulate
from granular_pyg.errors import InputError
from granular_pyg.evaluation import evaluate_pair
from granular_pyg.inference import frames_per_step, load_simulator, rollout_trajectory
from granular_pyg.io import Trajectory, read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scene_start import recorded_part, scene_start, whole_job_scalars
from granular_pyg.scenes import Scene

#: Targets: the learned rollout against serial LIGGGHTS (on a GPU: against LIGGGHTS on all
#: cores), as speed-ups; the discharge-rate error of that rollout.
SPEEDUP_OVER_SERIAL = 20.0
GPU_SPEEDUP_OVER_ALL_CORES = 100.0
MAX_DISCHARGE_ERROR = 0.1
#: Whole-job targets: the discharged fraction within 2 points, at most 0.5% of the bed leaked.
MAX_FRACTION_ERROR = 0.02
MAX_LEAKED_FRACTION = 0.005

LOOP_TIME = re.compile(r"^Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps", re.M)


def loop_times(log: Path) -> tuple[float, float]:
    """``(recorded_s, whole_s)``: seconds LIGGGHTS spent in the runs after the first (the
    recorded flow phase) and in all of them (the whole job: fill, settle and the recorded
    phase), from its ``Loop time`` lines."""
    loops = [float(m.group(1)) for m in LOOP_TIME.finditer(log.read_text())]
    if len(loops) < 2:
        raise InputError(f"{log}: expected a settle run and recorded runs, found {len(loops)}")
    return sum(loops[1:]), sum(loops)


def recorded_loop_time(log: Path) -> float:
    """Seconds LIGGGHTS spent in the runs after the first (the fill-and-settle run)."""
    return loop_times(log)[0]


def rerun_liggghts(
    truth: Trajectory | Scene, mpi_procs: int = 1, seed: int | None = None
) -> tuple[float, DemRun, float, Trajectory]:
    """Run a Scene (``truth``'s, with its seed, or a Scene itself) with LIGGGHTS on
    ``mpi_procs`` processes.

    Returns:
        ``(recorded_s, result, whole_s, trajectory)``: LIGGGHTS's loop time of the recorded
        phase (s, the fill-and-settle run left out), the run's :class:`DemRun`, its loop time
        of the whole job (fill + settle + recorded, s) and the trajectory it recorded.
    """
    scene = truth if isinstance(truth, Scene) else truth.scene
    if seed is None:
        seed = 0 if isinstance(truth, Scene) else int(truth.metadata.get("seed", 0))
    with tempfile.TemporaryDirectory(prefix="bench_liggghts_") as tmp:
        traj, dem = simulate(
            scene, seed, tmp, keep_workdir=True, mpi_procs=mpi_procs, progress=False
        )
        recorded, whole = loop_times(Path(tmp) / "log.liggghts")
        return recorded, dem, whole, traj


def load_scene(scene: str, num_particles: int | None = None) -> Scene:
    """The Scene of a scene config: a shipped name (``hopper``, ``mesh_silo``) or the path of
    a scene YAML (``conf/scene/mesh.yaml``'s format), scaled to ``num_particles`` (see
    :func:`scaled_build`)."""
    from omegaconf import OmegaConf

    from granular_pyg.config import CONF_DIR

    path = Path(scene).expanduser()
    if not (path.suffix in (".yaml", ".yml") or "/" in scene):
        path = CONF_DIR / "scene" / f"{scene}.yaml"
    if not path.is_file():
        raise InputError(f"scene: {scene} is neither a shipped scene nor a YAML file; check it")
    build = OmegaConf.to_container(OmegaConf.load(path), resolve=True)["build"]
    build = scaled_build(build, num_particles)
    return hydra.utils.instantiate(build, _convert_="all")


def scaled_build(build: dict, num_particles: int | None) -> dict:
    """A scene builder's arguments for ``num_particles`` particles of the same size, in the same
    equipment scaled to hold them:

    - the built-in hopper (``make_hopper``): its ``depth`` (the slot's length) times the count's
      ratio: the same quasi-2D flow per unit depth, Beverloo's rate proportional to it;
    - a mesh scene (``make_mesh_scene``): its ``scale`` times the cube root of the ratio:
      every length of the equipment (walls, insertion region, outlet) grows, the particles do
      not, so the bed's height in particle diameters grows with it;
    - the drum (``make_drum``): its ``length`` times the ratio.

    Returns ``build`` unchanged when ``num_particles`` is None.
    """
    if num_particles is None:
        return build
    build = dict(build)
    target = str(build.get("_target_", ""))
    count = build.get("num_particles")
    if not count:
        raise InputError(f"scene: {target} gives no num_particles to scale from")
    ratio = int(num_particles) / float(count)
    if target.endswith("make_hopper"):
        build["depth"] = float(build["depth"]) * ratio
    elif target.endswith("make_mesh_scene"):
        build["scale"] = float(build.get("scale", 1.0)) * ratio ** (1.0 / 3.0)
    elif target.endswith("make_drum"):
        build["length"] = float(build["length"]) * ratio
    else:
        raise InputError(f"num_particles: no rule to scale a scene built by {target}")
    build["num_particles"] = int(num_particles)
    return build


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
    scene: str | None = None,
    num_particles: int | None = None,
    whole_job: bool = True,
    seed: int = 0,
) -> SuiteResult:
    """Run the suite; see the module docstring. With ``wall_guard`` the learned rollout is
    also timed with the wall guard (a second row); each of ``precisions`` (the network's, see
    ``LearnedSimulator.set_network_precision``) gets its rows, and the targets are those of the
    last precision's unguarded rollout. ``repeats`` is unused (one run each).

    ``scene`` (a shipped scene's name or a scene YAML) and/or ``num_particles`` (the scene
    scaled to that count, :func:`scaled_build`): LIGGGHTS runs that Scene first (its first
    ``mpi_procs``) and its recording is the ground truth; else the ground truth is
    ``trajectory`` (default the bundled hopper test trajectory) and LIGGGHTS reruns its Scene.
    With ``whole_job`` every learned row also runs the whole job from the Scene alone
    (:mod:`granular_pyg.scene_start`: packed at rest, fill, settle, discharge) against
    LIGGGHTS's whole job (all its loop times).
    """
    if scene is not None or num_particles is not None:
        base = scene or "hopper"
        built = load_scene(base, None if num_particles is None else int(num_particles))
        source = f"scene `{base}`" + (f" at {num_particles} particles" if num_particles else "")
        truth = None
    else:
        truth = read_trajectory(trajectory or sample_files("hopper", "test")[0])
        built = truth.scene
        source = f"Scene of `{Path(trajectory or sample_files('hopper', 'test')[0]).name}`"
    rows, results = [], {}
    for procs in mpi_procs:
        loop, dem, whole, recorded = rerun_liggghts(
            built if truth is None else truth, procs, seed if truth is None else None
        )
        if truth is None:
            truth = recorded  # the first run's recording is the ground truth
        simulated = float(truth.times[-1] - truth.times[0])
        rows.append(
            {
                "simulator": f"LIGGGHTS, {procs} MPI process{'es' if procs > 1 else ''}",
                "simulated_s": simulated,
                "wall_s": loop,
                "wall_s_per_simulated_s": loop / simulated,
                "whole_job_s": whole,
                "whole_job_simulated_s": float(built.settle_time) + simulated,
                "whole_run_s": dem.wall_time_s,
            }
        )
    scene_obj = truth.scene
    simulated = float(truth.times[-1] - truth.times[0])
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
        options = {"progress": False, "skin": skin, "wall_guard": guarded, "precision": precision}
        with torch.inference_mode():
            synchronize(device)
            start = time.perf_counter()
            pred = rollout_trajectory(sim, truth, **options)
            synchronize(device)
            wall = time.perf_counter() - start
        scalars = evaluate_pair(truth, pred).scalars
        learned_sim = float(pred.times[-1] - pred.times[pred.metadata["initial_frames"] - 1])
        row = {
            "simulator": f"learned ({model.get('normals')}, {processor_name(model)}, "
            f"latent {model['latent']}, k = {pred.metadata['frames_per_step']}"
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
        if whole_job:
            row |= _whole_job_row(sim, truth, options, device, seed)
        rows.append(row)
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
    if whole_job:
        own = rows[-1]
        whole_serial = rows[0]["whole_job_s"]
        results |= {
            "liggghts_serial_whole_job_s": whole_serial,
            "learned_whole_job_s": own["whole_job_wall_s"],
            "learned_whole_job_speedup_over_serial": whole_serial / own["whole_job_wall_s"],
            "whole_job_discharge_rate_rel_error": own["whole_job_discharge_rate_rel_error"],
            "whole_job_discharged_fraction_error": own["whole_job_discharged_fraction_error"],
            "whole_job_leaked_fraction": own["whole_job_leaked_particles"] / truth.num_particles,
        }
        targets += [
            Target(
                "learned whole job (from the scene alone) / serial LIGGGHTS's whole job",
                results["learned_whole_job_speedup_over_serial"],
                ">=",
                SPEEDUP_OVER_SERIAL,
            ),
            Target(
                "whole job: discharge-rate error",
                own["whole_job_discharge_rate_rel_error"],
                "<=",
                MAX_DISCHARGE_ERROR,
            ),
            Target(
                "whole job: discharged fraction error (points)",
                abs(own["whole_job_discharged_fraction_error"]),
                "<=",
                MAX_FRACTION_ERROR,
            ),
            Target(
                "whole job: leaked fraction",
                results["whole_job_leaked_fraction"],
                "<=",
                MAX_LEAKED_FRACTION,
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
        f"{source} ({truth.num_particles} particles, {simulated:g} s recorded after "
        f"{scene_obj.settle_time:g} s of fill and settle, frames every "
        f"{truth.frame_dt * 1e3:g} ms, DEM dt {scene_obj.dem_dt:g} s); model `{ckpt}`; "
        f"{threads} torch threads, learned rollout on {device}. Flow phase: LIGGGHTS's loop "
        "time of the recorded runs against the learned rollout from its first recorded frames. "
        "Whole job: all of LIGGGHTS's loop times (fill, settle, recorded) against the learned "
        "rollout from the Scene alone (particles packed at rest in the insertion region)."
    )
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh([r["simulator"] for r in rows], [r["wall_s_per_simulated_s"] for r in rows])
    ax.set_xlabel("wall s per simulated s (flow phase)")
    fig.tight_layout()
    return SuiteResult(rows, results, targets, fig, notes)


def _whole_job_row(sim, truth: Trajectory, options: dict, device: str, seed: int) -> dict:
    """The learned whole job: from ``truth``'s Scene alone to its last recorded time, timed,
    and its discharge against ``truth`` (``whole_job_*`` keys)."""
    k = frames_per_step(sim, float(truth.frame_dt))
    start = scene_start(truth.scene, sim.history, k, seed=seed)
    if start.num_particles != truth.num_particles:
        raise InputError(
            f"scene: LIGGGHTS inserted {truth.num_particles} of the scene's "
            f"{start.num_particles} particles; the whole job compares complete fills only"
        )
    steps = round((float(truth.times[-1]) - float(start.times[-1])) / float(sim.dt))
    with torch.inference_mode():
        synchronize(device)
        begin = time.perf_counter()
        whole = rollout_trajectory(sim, start, steps, name="the scene's packing", **options)
        synchronize(device)
        wall = time.perf_counter() - begin
    scalars = evaluate_pair(truth, recorded_part(whole, truth)).scalars
    whole_job_scalars(scalars, whole)
    return {
        "whole_job_wall_s": wall,
        "whole_job_simulated_s": scalars["rollout_simulated_s"],
        "whole_job_discharge_rate_rel_error": scalars["discharge_rate_rel_error"],
        "whole_job_discharged_fraction_truth": scalars["discharged_fraction_truth"],
        "whole_job_discharged_fraction_pred": scalars["discharged_fraction_pred"],
        "whole_job_discharged_fraction_error": scalars["discharged_fraction_error"],
        "whole_job_leaked_particles": scalars["leaked_particles"],
    }
