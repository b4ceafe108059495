"""Suite ``scaling``: graph + wall-node construction and one model step against the particle
count and the triangle count, with fitted exponents and peak memory.

Particles are packed into the bench hopper funnel (``bench.meshes``); each measurement runs in
a fresh process so that its peak resident memory (``ru_maxrss``) is its own. Times are medians
of ``repeats`` runs after a warm-up. The exponent ``b`` of ``time ~ a n^b`` is a least-squares
fit in log-log space over the sizes measured.
"""

from __future__ import annotations

import multiprocessing as mp
import resource

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from granular_pyg.bench.report import SuiteResult


def _measure(
    kind: str,
    particles: int,
    triangles: int,
    radius: float,
    repeats: int,
    precision: str = "32",
    model_overrides: tuple[str, ...] = (),
    threads: int = 2,
) -> dict:
    """One measurement, run in a child process with ``threads`` torch threads (the bench's
    ``threads``); returns seconds and peak RSS (MiB).
    ``precision`` is the network's for a model step (``"32"`` or ``"bf16"``);
    ``model_overrides`` are Hydra overrides of the training config's model."""
    from hydra.utils import instantiate

    from granular_pyg.bench.meshes import funnel_mesh, packed_particles
    from granular_pyg.bench.report import time_call
    from granular_pyg.config import compose
    from granular_pyg.geometry import WallIndex
    from granular_pyg.heap import keep_freed_memory
    from granular_pyg.transforms import radius_graph

    torch.set_num_threads(threads)
    keep_freed_memory()  # as the commands do (a spawned child does not inherit it)
    vertices, faces = funnel_mesh(triangles)
    pos = packed_particles(particles, radius=radius).float()
    cutoff = 3.75 * radius  # the model's R = 7.5 mm for 2 mm particles
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = {"particles": int(pos.shape[0]), "triangles": int(faces.shape[0])}
    with torch.inference_mode():
        if kind == "graph":
            index = WallIndex(vertices.float(), faces)

            def build():
                edges = radius_graph(pos, cutoff)
                pairs = index.pairs(pos, cutoff)
                return edges, pairs

            edges, pairs = build()
            out["seconds"] = time_call(build, repeats)
            out["edges"] = int(edges.shape[1])
            out["wall_nodes"] = int(pairs.tri_idx.numel())
        else:
            from granular_pyg.scenes import Wall, WallSet
            from granular_pyg.scenes.scene import ParticleSpec, Scene

            scene = Scene(
                "bench",
                [Wall("funnel", vertices.numpy(), faces.numpy())],
                ParticleSpec(count=particles, radius=radius, fill_lo=(0, 0, 0), fill_hi=(1, 1, 1)),
            )
            walls = WallSet(scene)
            overrides = [f"model.radius={cutoff}", *model_overrides]
            sim = instantiate(compose("train", overrides).model).eval()
            sim.set_network_precision(precision)
            out["precision"] = precision
            out["parameters"] = sum(p.numel() for p in sim.parameters())
            seq = pos[:, None].repeat(1, sim.history + 1, 1)
            graph = sim.build_graph(seq, walls, 0.0)
            out["seconds"] = time_call(lambda: sim(sim.build_graph(seq, walls, 0.0)), repeats)
            out["edges"] = int(graph.edge_index.shape[1])
            out["wall_nodes"] = int(graph.is_wall.sum())
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out["peak_rss_mib"] = peak / 1024.0
    out["extra_rss_mib"] = (peak - base) / 1024.0
    return out


def _in_child(*args) -> dict:
    with mp.get_context("spawn").Pool(1) as pool:
        return pool.apply(_measure, args)


def _exponent(sizes: list[int], seconds: list[float]) -> float:
    return float(np.polyfit(np.log(sizes), np.log(seconds), 1)[0])


def run(
    particle_counts: tuple[int, ...] = (1000, 3000, 10000, 30000, 100000),
    model_particle_counts: tuple[int, ...] = (1000, 3000, 10000, 30000, 100000),
    triangle_counts: tuple[int, ...] = (100, 1000, 10000, 100000),
    fixed_triangles: int = 424,
    fixed_particles: int = 20000,
    particle_radius: float = 0.0006,
    repeats: int = 3,
    precisions: tuple[str, ...] = ("32",),
    model_overrides: tuple[str, ...] = (),
) -> SuiteResult:
    """Run the suite; see the module docstring. ``particle_radius`` (m) sets the packing and
    the cut-off (3.75 radii, the model's 7.5 mm for 2 mm particles); the model step is
    measured once per network precision in ``precisions`` (``"32"``, ``"bf16"``), for the
    default model changed by ``model_overrides`` (e.g. ``["model.latent=32"]``)."""
    model_overrides = tuple(str(o) for o in model_overrides)
    threads = torch.get_num_threads()  # the bench's one `threads` setting (bench.yaml)
    rows = []
    precisions = tuple(str(p) for p in precisions)  # `[32,bf16]` on the command line: 32 an int
    model_sweeps = [
        (f"model step {p}" if len(precisions) > 1 else "model step", p) for p in precisions
    ]
    sweeps = (
        [("graph", "particles", [(n, fixed_triangles) for n in particle_counts], "32")]
        + [
            (kind, "particles", [(n, fixed_triangles) for n in model_particle_counts], p)
            for kind, p in model_sweeps
        ]
        + [("graph", "triangles", [(fixed_particles, t) for t in triangle_counts], "32")]
    )
    results = {}
    for kind, axis, sizes, precision in sweeps:
        measured = []
        for n, t in sizes:
            what = "graph" if kind == "graph" else "model"
            row = _in_child(
                what, n, t, particle_radius, repeats, precision, model_overrides, threads
            )
            measured.append(row | {"what": kind, "against": axis})
        xs = [r[axis] for r in measured]
        b = _exponent(xs, [r["seconds"] for r in measured])
        for r in measured:
            r["fitted_exponent"] = b
        rows += measured
        results[f"scaling/{kind}/{axis}/exponent"] = b
        results[f"scaling/{kind}/{axis}/peak_rss_mib_max"] = max(
            r["peak_rss_mib"] for r in measured
        )
    changed = f" with {', '.join(model_overrides)}" if model_overrides else ""
    notes = (
        f"Bench funnel (`bench.meshes`), particles of radius {particle_radius * 1e3:g} mm packed "
        f"on a jittered lattice, cut-off {3.75 * particle_radius * 1e3:g} mm; graph = radius "
        "graph + wall pairs (WallIndex); model step = build_graph + forward of the default v3 "
        f"model (bgnn, latent 128){changed}. Each size in a fresh process (peak RSS its own)."
    )
    return SuiteResult(rows, results, [], _figure(rows), notes)


def _figure(rows: list[dict]):
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    for kind in dict.fromkeys(r["what"] for r in rows if r["against"] == "particles"):
        part = [r for r in rows if r["what"] == kind and r["against"] == "particles"]
        a.loglog([r["particles"] for r in part], [r["seconds"] for r in part], "o-", label=kind)
    a.set_xlabel("particles")
    a.set_ylabel("s per call")
    a.legend()
    part = [r for r in rows if r["against"] == "triangles"]
    b.loglog([r["triangles"] for r in part], [r["seconds"] for r in part], "o-")
    b.set_xlabel("triangles")
    b.set_ylabel("graph s per call")
    fig.tight_layout()
    return fig
