"""Suite ``radius_graph``: the radius-graph backends on packed particles, ``scipy`` against
``torch_cluster``.

Times :func:`granular_pyg.transforms.radius_graph.radius_graph` with each backend (the whole
function: candidate search, exact test, both directions, sort) and bare
``cKDTree(pos).query_pairs(r)`` on the same points, so the overhead of the exact, sorted
output over the raw search shows. Points sit on a cubic lattice of spacing 3 mm with uniform
jitter (+-10 % of a spacing), float32, like packed 3 mm particles; the cut-off is 2.5 spacings
(58-68 neighbours per point, fewer at the surface).

``python -m granular_pyg.bench suite=radius_graph`` writes the table (``report.md``) and the
times (``results.json``); the bench's ``threads`` sets the torch threads.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable

import torch

from granular_pyg.bench.report import SuiteResult, Target
from granular_pyg.io import markdown_table
from granular_pyg.transforms.radius_graph import radius_graph

SPACING = 0.003  # m


def jittered_lattice(num_points: int, spacing: float = SPACING, seed: int = 0) -> torch.Tensor:
    """``[num_points, 3]`` float32 points (m): the first ``num_points`` sites of a cubic lattice
    of ``spacing`` (a cube as near as possible), each moved by up to ``0.1 spacing`` per axis.
    """
    side = math.ceil(num_points ** (1 / 3))
    axis = torch.arange(side, dtype=torch.float64) * spacing
    sites = torch.cartesian_prod(axis, axis, axis)[:num_points]
    g = torch.Generator().manual_seed(seed)
    jitter = (torch.rand(sites.shape, generator=g, dtype=torch.float64) - 0.5) * 0.2 * spacing
    return (sites + jitter).float()


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def measure(
    num_points: tuple[int, ...] = (2000, 10000, 50000),
    radius_in_spacings: float = 2.5,
    repeats: int = 5,
) -> list[dict]:
    """Time both backends and bare ``query_pairs`` per point count (medians after a warm-up).

    Args:
        num_points: point counts to measure.
        radius_in_spacings: cut-off in lattice spacings (3 mm each).
        repeats: timed runs per measurement; the median is reported.

    Returns:
        One dict per point count: ``num_points``, ``edges`` (directed), ``scipy_s``,
        ``torch_cluster_s``, ``query_pairs_s`` (s), ``torch_cluster_over_scipy``,
        ``scipy_over_query_pairs`` and ``same_edges`` (the backends agree exactly).
    """
    from scipy.spatial import cKDTree

    radius = radius_in_spacings * SPACING
    rows = []
    for n in num_points:
        pos = jittered_lattice(n)
        by_scipy = radius_graph(pos, radius, backend="scipy")
        by_cluster = radius_graph(pos, radius, backend="torch_cluster")
        scipy_s = _median_time(lambda p=pos: radius_graph(p, radius, backend="scipy"), repeats)
        cluster_s = _median_time(
            lambda p=pos: radius_graph(p, radius, backend="torch_cluster"), repeats
        )
        pos64 = pos.double().numpy()
        pairs_s = _median_time(
            lambda p=pos64: cKDTree(p).query_pairs(radius, output_type="ndarray"), repeats
        )
        rows.append(
            {
                "num_points": n,
                "edges": by_scipy.shape[1],
                "scipy_s": scipy_s,
                "torch_cluster_s": cluster_s,
                "query_pairs_s": pairs_s,
                "torch_cluster_over_scipy": cluster_s / scipy_s,
                "scipy_over_query_pairs": scipy_s / pairs_s,
                "same_edges": torch.equal(by_scipy, by_cluster),
            }
        )
    return rows


def format_table(rows: list[dict]) -> str:
    """The rows of :func:`measure` as a Markdown table (times in ms)."""
    columns = [
        "points",
        "edges",
        "scipy (ms)",
        "torch_cluster (ms)",
        "query_pairs (ms)",
        "torch_cluster / scipy",
        "scipy / query_pairs",
        "same edges",
    ]
    cells = [
        [
            f"{r['num_points']:,}",
            f"{r['edges']:,}",
            f"{1e3 * r['scipy_s']:.1f}",
            f"{1e3 * r['torch_cluster_s']:.1f}",
            f"{1e3 * r['query_pairs_s']:.1f}",
            f"{r['torch_cluster_over_scipy']:.2f}",
            f"{r['scipy_over_query_pairs']:.2f}",
            "yes" if r["same_edges"] else "NO",
        ]
        for r in rows
    ]
    return markdown_table(columns, cells, align="rrrrrrrc")


def run(
    num_points: tuple[int, ...] = (2000, 10000, 50000),
    radius_in_spacings: float = 2.5,
    repeats: int = 5,
) -> SuiteResult:
    """The suite: :func:`measure`'s rows, the times per point count, and the target that both
    backends return the same edges."""
    rows = measure(tuple(num_points), radius_in_spacings, repeats)
    results = {}
    for row in rows:
        n = row["num_points"]
        for key in ("scipy_s", "torch_cluster_s", "query_pairs_s"):
            results[f"{n}/{key}"] = row[key]
    same = float(all(row["same_edges"] for row in rows))
    return SuiteResult(
        rows=rows,
        results=results,
        targets=[Target("backends return the same edges", same, ">=", 1.0)],
        notes=format_table(rows),
    )
