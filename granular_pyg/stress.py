"""``python -m granular_pyg.stress``: long rollouts of trained models, checked at every step.

Each case rolls a checkpoint out over the Scene of a ground-truth trajectory far beyond the
trajectory's end (the walls keep following the Scene: the drum keeps turning; a hopper case can
keep its lid closed, a resting bed) and checks every learned step for:

- NaN/Inf: the step's :class:`~granular_pyg.errors.NonFiniteError` (step and particle rows);
- kinetic-energy growth: kinetic energy (J, from the step's displacement) against the ground
  truth's largest, failing above ``ke_limit`` times it;
- leaked particles: centres whose step crossed a wall of the container (walls posed at the
  step's start and end, :func:`granular_pyg.metrics.leaked_mask`), judged before the outflow
  removes anyone;
- escaped particles: particles that left the Scene's simulation box other than through the
  outflow floor (through a wall); as LIGGGHTS deletes atoms that leave its box, they are
  removed (so a particle flung away cannot outgrow float32) and counted as leaked;
- particle-count drift: particles that vanished other than through the Scene's outflow;
- a crushed bed: particles whose centre is closer than the smallest radius to another's (half
  overlapping, which DEM never lets happen), failing when more than ``overlap_limit`` of the
  particles are; the case stops when more than ``crushed_stop`` are, as a crushed bed's
  particle graph grows towards N^2 edges (a model pressing its bed into a wall the guard
  holds gets there within a few steps);

and reports the first step where anything went wrong. With ``compare_float64`` a float64
rollout runs in lockstep and their divergence (RMS distance between the two, m) is recorded
against steps. Writes ``stress.json``, ``stress.csv`` (per sampled step), ``stress.md`` and
``stress.png`` into the run folder.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
from pathlib import Path

import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from granular_pyg.cli import command
from granular_pyg.errors import InputError, NonFiniteError
from granular_pyg.inference import initial_frames, load_simulator
from granular_pyg.io import Trajectory, atomic_write, command_line, markdown_table, read_trajectory
from granular_pyg.metrics import crushed_particles, leaked_mask
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import ParticleProps, WallGuard

__all__ = ["kinetic_energy", "stress_case"]


def kinetic_energy(prev: torch.Tensor, nxt: torch.Tensor, mass: torch.Tensor, dt: float) -> float:
    """Kinetic energy (J) of the particles present in both ``prev`` and ``nxt`` ``[N, 3]`` (m),
    with velocities ``(nxt - prev) / dt`` (m/s) and ``mass [N]`` (kg)."""
    both = torch.isfinite(prev).all(1) & torch.isfinite(nxt).all(1)
    vel = (nxt[both].double() - prev[both].double()) / dt
    return float(0.5 * (mass[both] * (vel * vel).sum(1)).sum())


def _masses(truth: Trajectory) -> torch.Tensor:
    density = truth.scene.materials.density if truth.scene is not None else 2500.0
    return torch.from_numpy(4.0 / 3.0 * math.pi * truth.radii.astype(np.float64) ** 3 * density)


def _truth_max_kinetic_energy(truth: Trajectory) -> float:
    mass = _masses(truth).numpy()
    vel = truth.velocities.astype(np.float64)
    energy = 0.5 * np.nansum(mass[None] * (vel * vel).sum(-1), axis=1)
    return float(energy.max())


def _outside(pos: torch.Tensor, box: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """``[N]`` bool: finite rows of ``pos [N, 3]`` (m) outside the box ``(lo, hi)`` (m)."""
    lo, hi = (b.to(pos.dtype) for b in box)
    return ((pos < lo) | (pos > hi)).any(1)


def _without_removals(truth: Trajectory) -> Trajectory:
    """``truth`` with every removable wall (the hopper's lid) kept for good."""
    scene = truth.scene
    walls = [dataclasses.replace(w, removal_time=None) for w in scene.walls]
    return dataclasses.replace(truth, scene=dataclasses.replace(scene, walls=walls))


def stress_case(
    sim,
    truth: Trajectory,
    steps: int,
    resting: bool = False,
    compare_float64: bool = True,
    ke_limit: float = 10.0,
    overlap_limit: float = 0.1,
    crushed_stop: float = 0.5,
    sample_every: int = 16,
    progress: bool = True,
    wall_guard: bool = False,
) -> tuple[dict, list[dict]]:
    """Roll ``sim`` out ``steps`` learned steps over ``truth``'s Scene, checking every step.

    Args:
        sim: a trained :class:`~granular_pyg.simulator.LearnedSimulator`.
        truth: ground truth whose first ``H + 1`` states (every k-th frame) start the rollout.
        steps: learned steps (any number; the Scene's walls are posed at every step's time).
        resting: keep removable walls (the hopper's lid) for good and start from the first
            frame at rest (its position repeated, zero velocity): a resting bed.
        compare_float64: also roll out in float64 and record the divergence.
        ke_limit: fail when the kinetic energy exceeds this times the truth's largest.
        overlap_limit: fail when more than this fraction of the present particles has a
            neighbour closer than the smallest radius.
        crushed_stop: stop the case when more than this fraction has.
        sample_every: steps between the sampled rows after the first ``sample_every ** 2``
            steps, each of which is a row (the checks run every step).
        progress: show a progress bar.
        wall_guard: roll out with the wall guard (:class:`~granular_pyg.simulator.WallGuard`,
            particle radii as margins); the summary counts its corrections.

    Returns:
        ``(summary, rows)``: the summary (``first_failure_step`` -1 when none, ``failure``,
        maxima, counts) and one row per sampled step (``step``, ``time_s``,
        ``kinetic_energy_j``, ``present``, ``leaked``, ``drift``, ``overlapping``,
        ``divergence_m``).
    """
    if steps < 1:
        raise InputError(f"steps: expected a positive number of learned steps, got {steps}")
    k, initial = initial_frames(sim, truth)
    closers = {w.name for w in truth.scene.walls if w.removal_time is not None}  # the lid
    if resting:
        truth = _without_removals(truth)
        initial = np.zeros_like(initial)
    scene, walls = truth.scene, WallSet(truth.scene)
    start = torch.from_numpy(truth.positions[initial]).permute(1, 0, 2).contiguous()
    radii = torch.from_numpy(truth.radii).double()
    props = ParticleProps.of(truth)  # radius and material inputs of models that take them
    dt, t0 = float(sim.dt), float(truth.times[initial[-1]])
    mass, tol = _masses(truth), float(truth.radii.min())
    ke_truth = _truth_max_kinetic_energy(truth)
    outflow = scene.outflow_z
    box = (torch.tensor(scene.domain_lo), torch.tensor(scene.domain_hi))
    rows, leaked_ever = [], np.zeros(truth.num_particles, dtype=bool)
    summary = {
        "steps": steps,
        "k": k,
        "dt_s": dt,
        "particles": truth.num_particles,
        "resting": resting,
        "wall_guard": wall_guard,
        "truth_max_kinetic_energy_j": ke_truth,
        "first_failure_step": -1,
        "failure": "",
        "steps_done": 0,
        "max_kinetic_energy_ratio": 0.0,
        "left_through_outflow": 0,
        "escaped_box": 0,
        "drift": 0,
        "max_overlapping_particles": 0,
        "max_divergence_m": 0.0,
    }
    guard = WallGuard(radii) if wall_guard else None
    # the float64 twin runs in lockstep inside the check, from the same initial states
    twin = {"seq": start.double(), "guard": WallGuard(radii) if wall_guard else None}

    def fail(step: int, why: str) -> None:
        if summary["first_failure_step"] < 0:
            summary["first_failure_step"], summary["failure"] = step, why

    def check(s: int, time: float, seq: torch.Tensor, new: torch.Tensor) -> bool:
        nxt = {"float32": new}
        if compare_float64:
            nxt["float64"] = sim.step(twin["seq"], walls, time, guard=twin["guard"], props=props)
        before = torch.isfinite(seq[:, -1]).all(1)
        out = new[:, 2] < outflow if outflow is not None else torch.zeros_like(before)
        # As in LIGGGHTS, a particle that leaves the simulation box is gone; other than
        # through the outflow floor it escaped through a wall.
        outside = {name: _outside(pos, box) for name, pos in nxt.items()}
        escaped = outside["float32"] & ~out & before
        n_escaped = int(escaped.sum())
        # Moves through a wall (the lid while present), judged before anyone is removed.
        moves = torch.stack([seq[:, -1], new]).numpy()
        now = leaked_mask(moves, scene, np.array([time, time + dt]), walls=walls, initial=False)[1]
        for name in nxt:
            nxt[name][outside[name]] = float("nan")
        after = torch.isfinite(new).all(1)  # the box's floor is the outflow plane
        # Reaching the outflow through a closed outlet is a leak too.
        if any(w.present(time + dt) for w in scene.walls if w.name in closers):
            now |= (before & out).numpy()
        if n_escaped:
            fail(s, f"{n_escaped} particle(s) escaped the scene's box through a wall")
            now |= escaped.numpy()
        if now.any():
            fail(s, f"{int(now.sum())} particle(s) leaked through a wall")
        leaked_ever[:] |= now
        left = int((before & out).sum())
        drift = int(before.sum()) - int(after.sum()) - left - n_escaped
        summary["left_through_outflow"] += left
        summary["escaped_box"] += n_escaped
        summary["drift"] += drift
        if drift:
            fail(s, f"{drift} particle(s) vanished other than through the outflow")
        crushed = int(crushed_particles(new.numpy()[None], tol)[0])
        summary["max_overlapping_particles"] = max(summary["max_overlapping_particles"], crushed)
        n_after = max(int(after.sum()), 1)
        if crushed > overlap_limit * n_after:
            fail(s, f"{crushed} particles closer than a radius to another (a crushed bed)")
        crushed_bed = crushed > crushed_stop * n_after
        energy = kinetic_energy(seq[:, -1], new, mass, dt)
        ratio = energy / ke_truth if ke_truth > 0 else (math.inf if energy > 0 else 0.0)
        summary["max_kinetic_energy_ratio"] = max(summary["max_kinetic_energy_ratio"], ratio)
        if ratio > ke_limit:
            fail(s, f"kinetic energy {ratio:.3g} x the truth's largest")
        divergence = math.nan
        if compare_float64:
            a, b = new.double(), nxt["float64"]
            both = torch.isfinite(a).all(1) & torch.isfinite(b).all(1)
            if bool(both.any()):
                divergence = float(((a[both] - b[both]) ** 2).sum(1).mean().sqrt())
                summary["max_divergence_m"] = max(summary["max_divergence_m"], divergence)
            twin["seq"] = torch.cat([twin["seq"][:, 1:], b[:, None]], dim=1)
        summary["steps_done"] = s + 1
        if crushed_bed or s < sample_every**2 or s % sample_every == 0 or s == steps - 1:
            rows.append(
                {
                    "step": s,
                    "time_s": time + dt,
                    "kinetic_energy_j": energy,
                    "kinetic_energy_ratio": ratio,
                    "present": int(after.sum()),
                    "leaked": int(leaked_ever.sum()),
                    "drift": summary["drift"],
                    "overlapping": crushed,
                    "divergence_m": divergence,
                }
            )
        return crushed_bed  # its graph grows towards N^2 edges: every further step slower

    with torch.inference_mode():
        try:
            sim.rollout(
                start.float(),
                walls,
                t0,
                steps,
                outflow,
                progress,
                None,
                guard,
                check,
                keep=False,
                props=props,
            )
        except NonFiniteError as exc:
            fail(exc.step, f"NaN/Inf prediction for particle rows {exc.particle_ids[:10]}")
    if wall_guard:
        summary["wall_guard_corrections"] = guard.corrected
    summary["leaked_particles"] = int(leaked_ever.sum())
    summary["present_at_end"] = rows[-1]["present"] if rows else truth.num_particles
    return summary, rows


def _figure(results: dict[str, tuple[dict, list[dict]]]):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ("kinetic_energy_ratio", "kinetic energy / truth's largest"),
        ("divergence_m", "float32 - float64 RMS distance (m)"),
        ("present", "particles present"),
        ("leaked", "leaked particles (ever)"),
        ("overlapping", "particles closer than a radius to another"),
    )
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4))
    for name, (summary, rows) in results.items():
        steps = [r["step"] + 1 for r in rows]
        for ax, (key, label) in zip(axes, panels, strict=True):
            ax.plot(steps, [r[key] for r in rows], label=name, lw=1)
            ax.set_xscale("log", base=2)
            ax.set_xlabel("learned step")
            ax.set_ylabel(label)
        if summary["first_failure_step"] >= 0:
            for ax in axes:
                ax.axvline(summary["first_failure_step"] + 1, ls=":", lw=1, color="k")
    for ax in axes[:2]:  # log scale where there is something positive to show (not at step 1)
        values = [v for line in ax.get_lines() for v in line.get_ydata() if v is not None]
        if any(math.isfinite(float(v)) and float(v) > 0 for v in values):
            ax.set_yscale("log")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def _markdown(results: dict[str, tuple[dict, list[dict]]], command: str) -> str:
    columns = [
        "case", "steps done", "k", "particles", "first failure", "max KE / truth", "leaked",
        "left (outflow)", "escaped box", "drift", "max overlapping",
        "max float32-float64 divergence (m)", "wall-guard corrections",
    ]  # fmt: skip
    rows = []
    for name, (s, _) in results.items():
        first = "none" if s["first_failure_step"] < 0 else f"step {s['first_failure_step']}: "
        rows.append(
            [
                name,
                f"{s['steps_done']:,} / {s['steps']:,}",
                s["k"],
                s["particles"],
                first + s["failure"],
                f"{s['max_kinetic_energy_ratio']:.3g}",
                s["leaked_particles"],
                s["left_through_outflow"],
                s["escaped_box"],
                s["drift"],
                s["max_overlapping_particles"],
                f"{s['max_divergence_m']:.3g}",
                s.get("wall_guard_corrections", "off"),
            ]
        )
    table = markdown_table(columns, rows, align="lrrrlrrrrrrrr")
    return f"# Stress test\n\nCommand: `{command}`\n\n{table}\n\n![stress](stress.png)\n"


def stress(cfg: DictConfig, out_dir: Path) -> dict[str, dict]:
    """Run every case of ``cfg`` and write the report into ``out_dir``; returns the summaries."""
    torch.set_num_threads(cfg.threads)
    results = {}
    for name, case in cfg.cases.items():
        steps = int(cfg.quick_steps if cfg.quick else case.get("steps") or cfg.steps)
        sim, _ = load_simulator(case.ckpt)
        source = case.trajectory or sample_files(case.sample, "test")[0]
        truth = read_trajectory(source)
        print(f"{name}: {steps} learned steps of {case.ckpt} on {source}")
        results[name] = stress_case(
            sim,
            truth,
            steps,
            resting=bool(case.get("resting", False)),
            compare_float64=bool(case.get("compare_float64", cfg.compare_float64)),
            ke_limit=float(cfg.ke_limit),
            overlap_limit=float(cfg.overlap_limit),
            crushed_stop=float(cfg.crushed_stop),
            sample_every=int(cfg.sample_every),
            progress=bool(cfg.progress),
            wall_guard=bool(case.get("wall_guard", cfg.wall_guard)),
        )
    out_dir = Path(out_dir)
    command = command_line("granular_pyg.stress")
    with atomic_write(out_dir / "stress.json") as fh:
        json.dump({n: s for n, (s, _) in results.items()} | {"command": command}, fh, indent=2)
    buf = io.StringIO()
    writer = None
    for name, (_, rows) in results.items():
        for row in rows:
            if writer is None:
                writer = csv.DictWriter(buf, fieldnames=["case", *row])
                writer.writeheader()
            writer.writerow({"case": name} | row)
    with atomic_write(out_dir / "stress.csv") as fh:
        fh.write(buf.getvalue())
    with atomic_write(out_dir / "stress.png", "wb") as fh:
        _figure(results).savefig(fh, format="png", dpi=110, bbox_inches="tight")
    with atomic_write(out_dir / "stress.md") as fh:
        fh.write(_markdown(results, command))
    for name, (s, _) in results.items():
        first = "no failure" if s["first_failure_step"] < 0 else s["failure"]
        print(f"{name}: {s['steps_done']} steps, {first}")
    print(f"report: {out_dir / 'stress.md'}")
    return {n: s for n, (s, _) in results.items()}


@command("stress")
def main(cfg: DictConfig) -> None:
    stress(cfg, Path(HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    main()
