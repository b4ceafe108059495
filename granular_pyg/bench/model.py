"""Suite ``model``: graph + wall-node construction and one forward pass per processor.

On the bundled hopper sample (a flowing frame, every particle present then) with the default
model config (``conf/model/v3.yaml``: latent 128, 2-layer MLPs), for each processor of the zoo.
Times are medians (s) of ``repeats`` runs after one warm-up, in inference mode.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate

from granular_pyg.bench.report import SuiteResult, time_call
from granular_pyg.config import compose
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet


def _simulator(variant: str, processor: str):
    cfg = compose("bench", [f"+model={variant}", f"model/processor={processor}"])
    return instantiate(cfg.model).eval()


def run(
    processors: tuple[str, ...] = ("gns", "bgnn", "attention"),
    variant: str = "v3",
    frame: int = 20,
    repeats: int = 5,
) -> SuiteResult:
    """Run the suite; see the module docstring."""
    traj = read_trajectory(sample_files("hopper")[0])
    seq = torch.from_numpy(traj.positions[frame - 5 : frame + 1]).permute(1, 0, 2).contiguous()
    seq = seq[torch.isfinite(seq).all(2).all(1)]
    walls, time = WallSet(traj.scene), float(traj.times[frame])
    rows, results = [], {}
    for name in processors:
        sim = _simulator(variant, name)
        with torch.inference_mode():
            graph = sim.build_graph(seq, walls, time)
            build_s = time_call(lambda s=sim: s.build_graph(seq, walls, time), repeats)
            forward_s = time_call(lambda s=sim, g=graph: s(g), repeats)
        params = sum(p.numel() for p in sim.parameters())
        rows.append(
            {
                "processor": name,
                "particles": seq.shape[0],
                "wall_nodes": int(graph.is_wall.sum()),
                "edges": graph.edge_index.shape[1],
                "parameters": params,
                "graph_build_s": build_s,
                "forward_s": forward_s,
            }
        )
        results |= {
            f"model/{name}/graph_build_s": build_s,
            f"model/{name}/forward_s": forward_s,
            f"model/{name}/parameters": float(params),
        }
    notes = (
        f"Bundled hopper sample `{sample_files('hopper')[0].name}`, frame {frame} "
        f"(t = {time:.3f} s), model `{variant}`; graph build = radius graph + wall nodes + "
        "features; forward = encoder + processor + decoder, inference mode."
    )
    return SuiteResult(rows, results, [], _figure(rows), notes)


def _figure(rows: list[dict]):
    fig, ax = plt.subplots(figsize=(5, 3))
    names = [r["processor"] for r in rows]
    ax.bar(names, [r["graph_build_s"] * 1e3 for r in rows], label="graph + wall nodes")
    ax.bar(
        names,
        [r["forward_s"] * 1e3 for r in rows],
        bottom=[r["graph_build_s"] * 1e3 for r in rows],
        label="forward pass",
    )
    ax.set_ylabel("ms per step")
    ax.set_title("One learned step, bundled hopper")
    ax.legend()
    fig.tight_layout()
    return fig
