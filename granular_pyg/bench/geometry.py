"""Suite ``geometry``: wall-pair queries of :class:`WallIndex` against the dense computation.

Measured at BGNN's hopper scale (20,000 particles x 424 triangles) and on a finely tessellated
hopper (20,000 triangles). Targets: the index at least 20x faster than dense at 424
triangles; at 20,000 triangles, within 2x of the 424-triangle query time for the same number of
near pairs (a random subset of particles chosen so the pair counts match).
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from granular_pyg.bench.meshes import funnel_mesh, packed_particles
from granular_pyg.bench.report import SuiteResult, Target, time_call
from granular_pyg.geometry import WallIndex, dense_wall_pairs


def _subset_with_pairs(point_idx: torch.Tensor, num_points: int, want: int, seed: int = 0):
    """A random subset of points whose near-pair count first reaches ``want``."""
    per_point = torch.bincount(point_idx, minlength=num_points)
    order = torch.randperm(num_points, generator=torch.Generator().manual_seed(seed))
    reached = torch.cumsum(per_point[order], 0) >= want
    stop = int(reached.nonzero()[0, 0]) + 1 if bool(reached.any()) else num_points
    return order[:stop].sort().values


def run(
    num_particles: int = 20000,
    triangle_counts: tuple[int, ...] = (424, 20000),
    particle_radius: float = 0.001,
    cutoff: float = 0.005,
    dtype: str = "float32",
    cell_size: float = 1.0,
    repeats: int = 5,
    dense_repeats: int = 1,
    dense_chunk_pairs: int = 1 << 22,
) -> SuiteResult:
    """Run the suite; see the module docstring. Lengths in m, times in s."""
    dt = getattr(torch, dtype)
    points = packed_particles(num_particles, particle_radius).to(dt)
    rows, results, queries = [], {}, {}
    for num_tris in triangle_counts:
        vertices, faces = funnel_mesh(num_tris)
        vertices = vertices.to(dt)
        build_s = time_call(lambda v=vertices, f=faces: WallIndex(v, f)._grid(cutoff), 1, 0)
        index = WallIndex(vertices, faces, cell_size=cell_size)
        found = index.pairs(points, cutoff)  # also builds the grid (warm-up)
        query_s = time_call(lambda i=index: i.pairs(points, cutoff), repeats)
        candidates = len(index.candidates(points, cutoff)[0])
        triangles = vertices[faces]
        dense = dense_wall_pairs(points, triangles, cutoff, max_pairs_per_chunk=dense_chunk_pairs)
        dense_s = time_call(
            lambda t=triangles: dense_wall_pairs(
                points, t, cutoff, max_pairs_per_chunk=dense_chunk_pairs
            ),
            dense_repeats,
            warmup=0,
        )
        same = torch.equal(found.point_idx, dense.point_idx) and torch.equal(
            found.tri_idx, dense.tri_idx
        )
        if not same:
            raise AssertionError(f"WallIndex and dense disagree at {num_tris} triangles")
        near = len(found.point_idx)
        queries[num_tris] = (index, found)
        rows.append(
            {
                "triangles": num_tris,
                "particles": num_particles,
                "near_pairs": near,
                "candidates": candidates,
                "index_build_s": build_s,
                "index_query_s": query_s,
                "dense_s": dense_s,
                "speedup": dense_s / query_s,
                "same_pairs": same,
            }
        )
        key = f"geometry/{num_particles}x{num_tris}"
        results |= {
            f"{key}/near_pairs": float(near),
            f"{key}/index_build_s": build_s,
            f"{key}/index_query_s": query_s,
            f"{key}/dense_s": dense_s,
            f"{key}/speedup_vs_dense": dense_s / query_s,
        }

    small, large = min(triangle_counts), max(triangle_counts)
    targets = [Target(f"speedup vs dense at {num_particles}x{small}", rows[0]["speedup"], ">=", 20)]
    if large != small:
        # Same number of near pairs at the large mesh: a random subset of the particles.
        index, found = queries[large]
        want = rows[0]["near_pairs"]
        subset = points[_subset_with_pairs(found.point_idx, num_particles, want)]
        matched_pairs = len(index.query(subset, cutoff)[0])
        matched_s = time_call(lambda: index.pairs(subset, cutoff), repeats)
        ratio = matched_s / rows[0]["index_query_s"]
        results |= {
            f"geometry/{large}_tris_matched/particles": float(len(subset)),
            f"geometry/{large}_tris_matched/near_pairs": float(matched_pairs),
            f"geometry/{large}_tris_matched/index_query_s": matched_s,
            f"geometry/query_ratio_{large}_vs_{small}_same_pairs": ratio,
        }
        rows.append(
            {
                "triangles": large,
                "particles": len(subset),
                "near_pairs": matched_pairs,
                "candidates": len(index.candidates(subset, cutoff)[0]),
                "index_build_s": float("nan"),
                "index_query_s": matched_s,
                "dense_s": float("nan"),
                "speedup": float("nan"),
                "same_pairs": True,
            }
        )
        targets.append(
            Target(f"query time {large} / {small} triangles, same pairs", ratio, "<=", 2)
        )
    notes = (
        f"Hopper funnel (9 planar walls), {num_particles} particles of radius "
        f"{particle_radius} m packed from the lid up, wall cut-off {cutoff} m, {dtype}. "
        "The last row is the large mesh queried with a random subset of particles whose "
        "near-pair count matches the small mesh's."
    )
    return SuiteResult(rows, results, targets, _figure(rows), notes)


def _figure(rows: list[dict]):
    fig, ax = plt.subplots(figsize=(6, 3.5))
    labels = [f"{r['particles']}x{r['triangles']}\n{r['near_pairs']} pairs" for r in rows]
    x = torch.arange(len(rows)).float()
    dense = [r["dense_s"] for r in rows]
    index = [r["index_query_s"] for r in rows]
    ax.bar(x - 0.2, dense, 0.4, label="dense (BGNN)")
    ax.bar(x + 0.2, index, 0.4, label="WallIndex query")
    ax.set_xticks(x.tolist(), labels)
    ax.set_yscale("log")
    ax.set_ylabel("wall time per query (s)")
    ax.set_title("Particle-triangle pairs within the cut-off")
    ax.legend()
    fig.tight_layout()
    return fig
