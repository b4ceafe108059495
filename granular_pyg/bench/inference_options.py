"""Suite ``inference_options``: what the run-time switches of a learned step buy, measured.

One learned step (graph + wall nodes + features, then the forward pass) of the default V3
model (``processor`` as configured) on a flowing frame of the bundled hopper, timed side by side
(interleaved rounds, medians) under: autograd on (plain), ``torch.no_grad``,
``torch.inference_mode`` (what rollouts use), 1 against 2 torch threads, and the network
compiled with ``torch.compile(dynamic=True)`` (edge counts change every step, so shapes are
dynamic). The compile time is reported separately, and the compiled output is checked against
the eager one. The whole ``LearnedSimulator.step`` (with the integration) is timed without and
with the wall guard (``wall_guard=true``), for the guard's cost.
"""

from __future__ import annotations

import contextlib
import statistics
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate

from granular_pyg.bench.report import SuiteResult
from granular_pyg.config import compose
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import WallGuard


def _median_times(fns: dict, repeats: int) -> dict[str, float]:
    times: dict[str, list[float]] = {name: [] for name in fns}
    for round_ in range(repeats + 1):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            if round_:
                times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def run(
    processor: str = "bgnn",
    frame: int = 30,
    threads: int = 2,
    compile: bool = True,
    repeats: int = 5,
) -> SuiteResult:
    """Run the suite; see the module docstring."""
    cfg = compose("bench", ["+model=v3", f"model/processor={processor}"])
    torch.manual_seed(0)
    sim = instantiate(cfg.model).eval()
    traj = read_trajectory(sample_files("hopper", "test")[0])
    seq = torch.from_numpy(traj.positions[frame - 5 : frame + 1]).permute(1, 0, 2).contiguous()
    present = torch.isfinite(seq).all(2).all(1)
    seq = seq[present]
    walls, t = WallSet(traj.scene), float(traj.times[frame])
    margin = torch.from_numpy(traj.radii).double()[present]

    def step(net=None):
        graph = sim.build_graph(seq, walls, t)
        return (net or sim)(graph)

    def under(ctx, n_threads=threads, net=None):
        def fn():
            torch.set_num_threads(n_threads)
            with ctx():
                return step(net)

        return fn

    def whole_step(guarded: bool):
        def fn():
            torch.set_num_threads(threads)
            guard = WallGuard(margin) if guarded else None
            with torch.inference_mode():
                return sim.step(seq, walls, t, traj.scene.outflow_z, guard=guard)

        return fn

    fns = {
        "plain (autograd on)": under(contextlib.nullcontext),
        "no_grad": under(torch.no_grad),
        "inference_mode": under(torch.inference_mode),
        "inference_mode, 1 thread": under(torch.inference_mode, 1),
        "whole step (+ integration)": whole_step(False),
        "whole step + wall guard": whole_step(True),
    }
    compile_s, max_diff = float("nan"), float("nan")
    if compile:
        compiled_model = torch.compile(sim.model, dynamic=True)

        class _Compiled(torch.nn.Module):
            def forward(self, graph):
                out = compiled_model(graph.x, graph.edge_index, graph.edge_attr)
                return out[~graph.is_wall]

        compiled = _Compiled()
        start = time.perf_counter()
        with torch.inference_mode():
            got = step(compiled)
        compile_s = time.perf_counter() - start
        with torch.inference_mode():
            max_diff = float((got - step()).abs().max())
        fns["inference_mode + torch.compile"] = under(torch.inference_mode, net=compiled)
    medians = _median_times(fns, repeats)
    base = medians["inference_mode"]
    rows = [
        {"setting": name, "step_s": s, "relative_to_inference_mode": s / base}
        for name, s in medians.items()
    ]
    results = {f"{r['setting']}/step_s": r["step_s"] for r in rows}
    results["compile_s"] = compile_s
    results["compiled_max_abs_diff"] = max_diff
    torch.set_num_threads(threads)
    notes = (
        f"V3, `{processor}` processor, latent {cfg.model.latent}; {seq.shape[0]} particles of "
        f"`{sample_files('hopper', 'test')[0].name}` at frame {frame}; one step = graph + wall "
        f"nodes + features + forward. torch.compile: first call (compilation) {compile_s:.1f} s,"
        f" largest difference from eager {max_diff:.2g} (normalised acceleration)."
    )
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.barh([r["setting"] for r in rows], [1e3 * r["step_s"] for r in rows])
    ax.set_xlabel("ms per learned step")
    fig.tight_layout()
    return SuiteResult(rows, results, [], fig, notes)
