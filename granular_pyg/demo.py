"""``make demo``: the package end to end on real data, in about ten minutes on 2 CPU cores.

1. Geometry: the paper's virtual wall nodes for 20,000 particles in a 424-triangle hopper
   funnel, found with :class:`~granular_pyg.geometry.WallIndex` and checked against the dense
   computation (seconds).
2. Training: a small V3 model on the bundled LIGGGHTS hopper sample
   (``python -m granular_pyg.train +experiment=demo``), TensorBoard logs and checkpoints.
3. Rollout and evaluation of that model on the held-out test trajectory: metrics, figures in
   the paper's style and a Markdown report. Without a trained model (``--stages evaluate`` on
   a fresh machine) the shipped ``pretrained:hopper`` model is evaluated.

Prints where everything is.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from granular_pyg.bench.meshes import funnel_mesh, packed_particles
from granular_pyg.cli import reports_errors
from granular_pyg.config import compose
from granular_pyg.evaluate import evaluate
from granular_pyg.geometry import (
    WallIndex,
    canonical_normals,
    dense_wall_pairs,
    orientation_key,
    triangle_normals,
)
from granular_pyg.io import atomic_write
from granular_pyg.train import train


def geometry_demo(out: Path, particles: int = 20000, cutoff: float = 0.005) -> Path:
    """Stage 1: wall nodes of ``particles`` packed particles in a 424-triangle funnel within
    ``cutoff`` (m); returns the figure's path."""
    vertices, faces = funnel_mesh(424)
    points = packed_particles(particles, radius=0.001).float()
    index = WallIndex(vertices.float(), faces)

    start = time.perf_counter()
    pairs = index.pairs(points, cutoff)
    first = time.perf_counter() - start
    start = time.perf_counter()
    pairs = index.pairs(points, cutoff)
    again = time.perf_counter() - start
    start = time.perf_counter()
    dense = dense_wall_pairs(points, vertices.float()[faces], cutoff)
    dense_s = time.perf_counter() - start
    assert torch.equal(pairs.tri_idx, dense.tri_idx), "index and dense disagree"

    normals = canonical_normals(triangle_normals(vertices.float()[faces]))[pairs.tri_idx]
    near = torch.unique(pairs.point_idx).numel()
    print(f"hopper mesh: {faces.shape[0]} triangles; {particles} particles")
    print(f"wall nodes within {cutoff * 1000:.1f} mm: {len(pairs.tri_idx)} on {near} particles")
    print(
        f"WallIndex: first query (builds the grid) {first * 1e3:.1f} ms, then {again * 1e3:.1f} ms"
    )
    print(f"dense all-pairs (BGNN): {dense_s * 1e3:.1f} ms -> {dense_s / again:.0f}x faster")
    print(f"V3 normal features: {tuple(normals.shape)} (both orientations, smaller f_o first)")

    fig, ax = plt.subplots(figsize=(5, 6))
    ax.scatter(points[:, 0], points[:, 2], s=0.3, c="0.75", label="particles")
    wall = pairs.closest
    key = orientation_key(normals[:, :3])  # one colour per wall orientation
    ax.scatter(wall[:, 0], wall[:, 2], s=1.0, c=key, cmap="tab10", label="wall nodes")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal")
    ax.set_title("Virtual wall nodes (colour: f_o of the first normal)")
    ax.legend(loc="upper right", markerscale=8)
    figure = out / "wall_nodes.png"
    with atomic_write(figure, "wb") as fh:
        fig.savefig(fh, format="png", dpi=120, bbox_inches="tight")
    print(f"figure: {figure}")
    return figure


def training_demo(out: Path, overrides: list[str]) -> Path:
    """Stage 2: train the demo model (``conf/experiment/demo.yaml`` plus ``overrides``);
    returns its last checkpoint."""
    cfg = compose("train", ["+experiment=demo", *overrides])
    train(cfg, out)
    return out / "checkpoints" / "last.ckpt"


def evaluation_demo(out: Path, ckpt: Path | str, steps: int | None = None) -> Path:
    """Stage 3: roll the model out on the held-out test trajectory and evaluate it; returns
    the report's path."""
    overrides = [f"ckpt={ckpt}", f"out={out}", "splits=[test]"]
    if steps is not None:
        overrides.append(f"steps={steps}")
    return evaluate(compose("evaluate", overrides))


@reports_errors
def main(argv: list[str] | None = None) -> dict[str, Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--particles", type=int, default=20000)
    parser.add_argument("--cutoff", type=float, default=0.005, help="wall cut-off (m)")
    parser.add_argument(
        "--stages", default="geometry,train,evaluate", help="comma-separated stages to run"
    )
    parser.add_argument("--steps", type=int, default=None, help="rollout steps (default: all)")
    parser.add_argument("overrides", nargs="*", help="training config overrides (Hydra syntax)")
    args = parser.parse_args(argv)
    stages = set(args.stages.split(","))
    paths: dict[str, Path] = {}
    start = time.perf_counter()
    if "geometry" in stages:
        print("== 1. geometry: virtual wall nodes ==")
        paths["figure"] = geometry_demo(args.out / "geometry", args.particles, args.cutoff)
    if "train" in stages:
        print("== 2. training a small V3 model on the bundled hopper sample ==")
        paths["ckpt"] = training_demo(args.out / "train", args.overrides)
        paths["tensorboard"] = args.out / "train" / "tensorboard"
    if "evaluate" in stages:
        print("== 3. rollout and evaluation on the held-out test trajectory ==")
        trained = args.out / "train" / "checkpoints" / "last.ckpt"
        ckpt = paths.get("ckpt") or (trained if trained.is_file() else "pretrained:hopper")
        print(f"model: {ckpt}")
        paths["report"] = evaluation_demo(args.out / "evaluate", ckpt, args.steps)
    print(f"== done in {time.perf_counter() - start:.0f} s ==")
    for name, path in paths.items():
        print(f"{name:>12s}: {path}")
    if "tensorboard" in paths:
        print(f"view the training curves: tensorboard --logdir {paths['tensorboard']}")
    return paths


if __name__ == "__main__":
    main()
