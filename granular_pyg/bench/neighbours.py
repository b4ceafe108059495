"""Suite ``neighbours``: the radius graph against bare ``cKDTree.query_pairs``, and the
Verlet-style neighbour reuse over real LIGGGHTS motion.

1. ``radius_graph`` (scipy backend, the exact test and both directions; unsorted and sorted)
   against ``cKDTree(pos).query_pairs(r)`` on the same jittered-lattice points, timed side by
   side (medians after a warm-up).
2. BGNN's dense ``N x N`` particle graph against ours at its hopper scale (20,000 points),
   checked identical.
3. The graph of every learned step (every ``k``-th frame: the pretrained models' time-step
   multiples) of LIGGGHTS trajectories, built fresh each step or with a
   :class:`NeighbourList` of skin ``s``: time of the particle graph alone and of the whole
   ``build_graph`` (particle graph + wall nodes + features), and the number of searches. The
   ground-truth positions are replayed, so both paths see the same motion; the edges are
   checked equal every step. Cases: the first bundled test hopper while it discharges, the
   first bundled drum, and a hopper bed at rest behind its closed lid (run with LIGGGHTS
   here, about 10 s, as the bundled hoppers open after 20 ms).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate

from granular_pyg.bench.radius_graph import jittered_lattice
from granular_pyg.bench.report import SuiteResult, Target, time_call
from granular_pyg.config import compose
from granular_pyg.dem import simulate
from granular_pyg.io import Trajectory, read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet, make_hopper
from granular_pyg.transforms import NeighbourList, radius_graph

#: Graph radius (m) per scene, as the pretrained models.
RADII = {"hopper": 0.0075, "drum": 0.01}


def _interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median seconds of each ``fn``, timed in turn within each round (after a warm-up round),
    so that drift of the machine hits every candidate alike."""
    times: dict[str, list[float]] = {name: [] for name in fns}
    for round_ in range(repeats + 1):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            if round_:
                times[name].append(time.perf_counter() - start)
    return {name: statistics.median(ts) for name, ts in times.items()}


def _rounds(fn: Callable[[], object], repeats: int, budget_s: float = 0.5) -> int:
    """Rounds for :func:`_interleaved`: at least ``repeats`` and 11, and enough for ``fn`` to
    take about ``budget_s`` in all (a 4 ms search needs ~100 for a stable median), at most 401."""
    start = time.perf_counter()
    fn()
    once = max(time.perf_counter() - start, 1e-6)
    return int(min(max(repeats, 11, budget_s / once), 401))


def _query_pairs_rows(num_points, radius_in_spacings: float, repeats: int) -> list[dict]:
    from scipy.spatial import cKDTree

    rows = []
    r = radius_in_spacings * 0.003
    for n in num_points:
        pos = jittered_lattice(n)
        p64 = pos.double().numpy()
        t = _interleaved(
            {
                "bare": lambda p=p64: cKDTree(p).query_pairs(r, output_type="ndarray"),
                "unsorted": lambda p=pos: radius_graph(p, r, "scipy", sort=False),
                "sorted": lambda p=pos: radius_graph(p, r, "scipy"),
            },
            _rounds(lambda p=p64: cKDTree(p).query_pairs(r, output_type="ndarray"), repeats),
        )
        rows.append(
            {
                "part": "radius graph",
                "case": f"{n} points",
                "query_pairs_s": t["bare"],
                "unsorted_s": t["unsorted"],
                "sorted_s": t["sorted"],
                "unsorted_over_query_pairs": t["unsorted"] / t["bare"],
                "sorted_over_query_pairs": t["sorted"] / t["bare"],
            }
        )
    return rows


def dense_radius_graph(pos: torch.Tensor, radius: float, chunk: int = 2048) -> torch.Tensor:
    """BGNN's approach: the full ``N x N`` distance matrix (in row chunks to bound memory),
    thresholded; ``[2, E]`` sorted by (target, source) like ``radius_graph``."""
    r2 = torch.tensor(radius * radius, dtype=pos.dtype)
    parts = []
    for start in range(0, pos.shape[0], chunk):
        d = pos[start : start + chunk, None, :] - pos[None, :, :]
        d = d * d
        sq = (d[..., 0] + d[..., 1]) + d[..., 2]
        target, source = (sq < r2).nonzero(as_tuple=True)
        target = target + start
        keep = target != source
        parts.append(torch.stack([source[keep], target[keep]]))
    return torch.cat(parts, dim=1)


def _dense_rows(num_points: int, radius_in_spacings: float, repeats: int) -> list[dict]:
    pos = jittered_lattice(num_points)
    r = radius_in_spacings * 0.003
    dense = dense_radius_graph(pos, r)
    ours = radius_graph(pos, r)
    if not torch.equal(dense, ours):
        raise AssertionError("dense and radius_graph disagree")
    dense_s = time_call(lambda: dense_radius_graph(pos, r), max(1, repeats // 2))
    ours_s = time_call(lambda: radius_graph(pos, r), repeats)
    return [
        {
            "part": "dense N x N (BGNN)",
            "case": f"{num_points} points",
            "dense_s": dense_s,
            "radius_graph_s": ours_s,
            "speedup": dense_s / ours_s,
        }
    ]


def _replay(sim, traj, skin: float | None, frames: range) -> dict:
    """Build the graph of each frame of ``traj`` in ``frames`` (its step is the learned step's
    frame multiple); return times (s) and the edges per frame. The particle graph alone and the
    whole ``build_graph`` are timed with a neighbour list each, as a rollout calls it once a
    step."""
    walls = WallSet(traj.scene)
    rg = sim.radius_graph
    nl, nl_build = (
        None if skin is None else NeighbourList(rg.radius, skin, rg.backend) for _ in range(2)
    )
    h, k = sim.history, frames.step
    graph_s = build_s = 0.0
    edges = []
    for f in frames:
        seq = torch.from_numpy(traj.positions[f - h * k : f + 1 : k]).permute(1, 0, 2)
        present = torch.isfinite(seq).all(2).all(1)
        seq = seq[present].contiguous()
        ids = present.nonzero().squeeze(1)
        start = time.perf_counter()
        last = seq[:, -1]
        e = radius_graph(last, rg.radius, rg.backend) if nl is None else nl(last, ids)
        graph_s += time.perf_counter() - start
        start = time.perf_counter()
        sim.build_graph(seq, walls, float(traj.times[f]), nl_build, ids)
        build_s += time.perf_counter() - start
        edges.append(e)
    return {
        "graph_s": graph_s,
        "build_s": build_s,
        "edges": edges,
        "builds": nl.builds if nl else len(frames),
        "refreshes": nl.refreshes if nl else 0,
        "plain": nl.plain if nl else 0,
    }


def resting_hopper(num_particles: int, steps: int, step_s: float) -> Trajectory:
    """A LIGGGHTS hopper bed at rest behind its closed lid: ``steps`` frames ``step_s`` apart
    after settling (the lid opens only after the last)."""
    duration = (steps + 1) * step_s
    scene = make_hopper(
        num_particles=num_particles,
        t_open=duration - 0.5 * step_s,
        duration=duration,
        frame_dt=step_s,
    )
    traj, _ = simulate(scene, seed=1, progress=False)
    return traj


def run(
    num_points: tuple[int, ...] = (2000, 10000, 50000),
    radius_in_spacings: float = 2.5,
    spans: dict | None = None,
    resting: dict | None = None,
    skins: tuple[float, ...] = (0.0005, 0.001, 0.002),
    dense_points: int = 20000,
    repeats: int = 5,
) -> SuiteResult:
    """Run the suite; see the module docstring.

    Args:
        spans: ``{scene: {phase: [first, last, k]}}``: frames ``first..last`` of the first
            bundled test trajectory of ``scene``, every ``k``-th (a learned step).
        resting: ``{num_particles, steps, step_s}`` of the hopper at rest run with LIGGGHTS;
            None: no such case.
        skins: Verlet skins (m).
        dense_points: size of the dense ``N x N`` comparison (BGNN's hopper: 20,000).
    """
    rows = _query_pairs_rows(num_points, radius_in_spacings, repeats)
    rows += _dense_rows(dense_points, radius_in_spacings, repeats)
    results = {"dense/speedup": rows[-1]["speedup"]}
    best_reuse = 0.0
    for row in rows[:-1]:
        results[f"radius_graph/{row['case']}/unsorted_over_query_pairs"] = row[
            "unsorted_over_query_pairs"
        ]
    cases = []  # (case, trajectory, graph radius (m), frames replayed)
    for scene, phases in (spans or {}).items():
        traj = read_trajectory(sample_files(scene, "test")[0])
        for phase, (first, last, k) in phases.items():
            cases.append((f"{scene} {phase}", traj, RADII[scene], range(first, last, k)))
    if resting:
        traj = resting_hopper(resting["num_particles"], resting["steps"], resting["step_s"])
        cases.append(("hopper at rest (closed lid)", traj, RADII["hopper"], range(traj.num_frames)))
    for case, traj, radius, frames in cases:
        sim = instantiate(compose("train", [f"model.radius={radius}"]).model).eval()
        span = range(max(frames.start, sim.history * frames.step), frames.stop, frames.step)
        span = span[: len(range(span.start, traj.num_frames, span.step))]
        with torch.inference_mode():
            fresh = _replay(sim, traj, None, span)
            for skin in skins:
                reuse = _replay(sim, traj, skin, span)
                pairs = zip(fresh["edges"], reuse["edges"], strict=True)
                if not all(torch.equal(a, b) for a, b in pairs):
                    raise AssertionError(f"{case}, skin {skin}: reused edges differ")
                speedup = fresh["graph_s"] / reuse["graph_s"]
                best_reuse = max(best_reuse, speedup)
                rows.append(
                    {
                        "part": "neighbour reuse",
                        "case": f"{case}, skin {skin * 1e3:g} mm",
                        "particles": traj.positions.shape[1],
                        "steps": len(span),
                        "frames_per_step": span.step,
                        "fresh_graph_s": fresh["graph_s"],
                        "reuse_graph_s": reuse["graph_s"],
                        "graph_speedup": speedup,
                        "fresh_build_s": fresh["build_s"],
                        "reuse_build_s": reuse["build_s"],
                        "build_speedup": fresh["build_s"] / reuse["build_s"],
                        "full_searches": reuse["builds"],
                        "partial_searches": reuse["refreshes"],
                        "plain_graphs": reuse["plain"],
                    }
                )
                key = f"reuse/{case}/skin_{skin * 1e3:g}mm/graph_speedup"
                results[key] = speedup
    worst = max(r["unsorted_over_query_pairs"] for r in rows if r["part"] == "radius graph")
    targets = [
        Target("radius graph (unsorted) / query_pairs, worst size", worst, "<=", 1.2),
        Target("neighbour reuse speed-up of the particle graph, best skin", best_reuse, ">=", 2.0),
    ]
    notes = (
        "Radius graph: jittered 3 mm lattice, float32, cut-off 2.5 spacings, scipy backend. "
        "Reuse: LIGGGHTS frames one learned step apart (the bundled test trajectories; a hopper "
        "at rest run here), graph radius 7.5 mm (hopper) / 10 mm (drum) as the pretrained "
        "models; edges checked identical to fresh every step. Plain graphs: steps where too "
        "many particles left their skin and the list returned a plain search instead."
    )
    return SuiteResult(rows, results, targets, _figure(rows), notes)


def _figure(rows: list[dict]):
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.5))
    graph = [r for r in rows if r["part"] == "radius graph"]
    names = [r["case"] for r in graph]
    a.bar(names, [r["unsorted_over_query_pairs"] for r in graph], label="unsorted")
    a.plot(names, [r["sorted_over_query_pairs"] for r in graph], "ko", label="sorted")
    a.axhline(1.2, color="r", lw=0.8)
    a.set_ylabel("time / query_pairs")
    a.legend()
    reuse = [r for r in rows if r["part"] == "neighbour reuse"]
    b.barh([r["case"] for r in reuse], [r["graph_speedup"] for r in reuse])
    b.axvline(2.0, color="r", lw=0.8)
    b.set_xlabel("particle-graph speed-up with reuse")
    fig.tight_layout()
    return fig
