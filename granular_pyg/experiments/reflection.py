r"""The paper's reflection toy experiment (Appendix B.1, Figures B.1/B.2): why wall normals are
fed in a canonical orientation.

A small ReLU MLP learns the reflection of a ray :math:`v` at a plane with normal :math:`n`,

.. math::

    \operatorname{Ref}_n(v) = v - 2 \frac{v \cdot n}{n \cdot n} n,

from the wall representation and :math:`v`. It is trained on four fixed walls of the cube
:math:`[-1, 1]^3` (left, right, bottom, top; ``z`` up) with outward normals and incident rays that
travel into the wall (:math:`v \cdot n > 0`), and evaluated on fresh rays at the same walls with
the normals as in training and inverted (:math:`-n`). The reflection itself does not depend on
the sign of :math:`n`, but an MLP fed the raw normal only ever saw :math:`v \cdot n > 0`:

- R1: :math:`n`; R2: :math:`n, -n` (raw, the mesh's orientation);
- R3: :math:`n` if :math:`f_o(n) \le f_o(-n)` else :math:`-n`; R4: that normal, then its negative
  (:func:`granular_pyg.geometry.canonical_normals`, bit-identical for :math:`n` and :math:`-n`).

``python -m granular_pyg.experiments.reflection`` (config ``conf/reflection.yaml``) writes
``results.json``, ``table.md``, ``table.csv`` and ``figures/reflection_{same,inverted}.png``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tqdm.auto import tqdm

from granular_pyg.cli import command
from granular_pyg.errors import InputError, check_tensor
from granular_pyg.geometry import canonical_normals
from granular_pyg.io import atomic_write, command_line, markdown_table
from granular_pyg.progress import show_progress

__all__ = [
    "KINDS",
    "WALLS",
    "check_config",
    "figure_rays",
    "make_reflection_data",
    "predict",
    "reflect",
    "reflection_figure",
    "represent",
    "run_experiment",
    "train_representation",
]

#: Outward unit normals of the four training walls of the cube ``[-1, 1]^3`` (``z`` up).
WALLS: dict[str, tuple[float, float, float]] = {
    "left": (-1.0, 0.0, 0.0),
    "right": (1.0, 0.0, 0.0),
    "bottom": (0.0, 0.0, -1.0),
    "top": (0.0, 0.0, 1.0),
}

#: Wall representations: name -> (feature width, label of the features for n as given).
KINDS: dict[str, tuple[int, str]] = {
    "R1": (3, "n"),
    "R2": (6, "n, -n"),
    "R3": (3, "n if f_o(n) <= f_o(-n) else -n"),
    "R4": (6, "(n, -n) if f_o(n) <= f_o(-n) else (-n, n)"),
}

#: Panel titles (mathtext) for the figures, for the normals as in training and inverted.
_TITLES = {
    False: {
        "truth": r"Ground truth: $n$",
        "R1": r"R1: $n$",
        "R2": r"R2: $n, -n$",
        "R3": r"R3: $n$ if $f_o(n) \leq f_o(-n)$ else $-n$",
        "R4": r"R4: $(n, -n)$ if $f_o(n) \leq f_o(-n)$ else $(-n, n)$",
    },
    True: {
        "truth": r"Ground truth: $-n$",
        "R1": r"R1: $-n$",
        "R2": r"R2: $-n, n$",
        "R3": r"R3: $-n$ if $f_o(-n) \leq f_o(n)$ else $n$",
        "R4": r"R4: $(-n, n)$ if $f_o(-n) \leq f_o(n)$ else $(n, -n)$",
    },
}

#: Config keys that must be positive integers, with a sensible value for the error message.
_POSITIVE_INTS = {
    "train_samples": 4096,
    "test_samples": 4096,
    "steps": 4000,
    "batch_size": 256,
    "hidden": 64,
    "layers": 2,
    "figure_rays": 4,
    "threads": 1,
}


def reflect(v: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    r"""Reflection at the plane through the origin with normal ``n``:
    :math:`v - 2 \frac{v \cdot n}{n \cdot n} n`.

    Args:
        v: ``[..., 3]`` rays (any unit, e.g. m/s).
        n: ``[..., 3]`` non-zero normals of any length, broadcastable against ``v``.

    Returns:
        ``[..., 3]`` reflected rays, same unit and length as ``v``; the same for ``n`` and ``-n``.

    Raises:
        InputError: if a normal is zero.
    """
    nn_ = (n * n).sum(dim=-1, keepdim=True)
    if bool((nn_ == 0).any()):
        raise InputError("n: a zero normal has no reflection plane; pass non-zero normals")
    return v - 2 * (v * n).sum(dim=-1, keepdim=True) / nn_ * n


def wall_normals(dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``[4, 3]`` outward unit normals of :data:`WALLS` (left, right, bottom, top)."""
    return torch.tensor(list(WALLS.values()), dtype=dtype)


def make_reflection_data(
    num: int, generator: torch.Generator | None = None, dtype: torch.dtype = torch.float32
) -> dict[str, torch.Tensor]:
    """Random incident rays at the four walls, cycled evenly (left, right, bottom, top, ...).

    Directions are uniform on the half sphere that points into the wall along its outward
    normal (``v . n > 0``: a ray inside the cube travelling towards the wall); ``|v| = 1``.

    Args:
        num: number of rays (at least 1).
        generator: torch random generator (for reproducibility).
        dtype: floating dtype of the tensors.

    Returns:
        ``{"wall": [num] int64 index into WALLS, "normals": [num, 3] outward unit normals,
        "incident": [num, 3] unit rays, "reflected": [num, 3] their reflections}``.
    """
    if num < 1:
        raise InputError(f"num: expected at least one ray, got {num}")
    wall = torch.arange(num) % len(WALLS)
    normals = wall_normals(dtype)[wall]
    v = torch.randn(num, 3, generator=generator, dtype=dtype)
    v = v / torch.linalg.vector_norm(v, dim=1, keepdim=True).clamp_min(torch.finfo(dtype).tiny)
    v = torch.where((v * normals).sum(dim=1, keepdim=True) < 0, -v, v)
    return {"wall": wall, "normals": normals, "incident": v, "reflected": reflect(v, normals)}


def represent(normals: torch.Tensor, kind: str) -> torch.Tensor:
    """The wall features of representation ``kind`` (paper's R1-R4).

    Args:
        normals: ``[N, 3]`` wall normals (as the mesh stores them).
        kind: ``"R1"`` (``n``), ``"R2"`` (``n, -n``), ``"R3"`` (canonical single normal) or
            ``"R4"`` (canonical ordered pair).

    Returns:
        ``[N, 3]`` (R1, R3) or ``[N, 6]`` (R2, R4); R3 and R4 are bit-identical for ``normals``
        and ``-normals``.
    """
    check_tensor("normals", normals, (None, 3))
    if kind == "R1":
        return normals
    if kind == "R2":
        return torch.cat([normals, -normals], dim=1)
    if kind == "R3":
        return canonical_normals(normals)[:, :3]
    if kind == "R4":
        return canonical_normals(normals)
    raise InputError(f"kind: expected one of {list(KINDS)}, got {kind!r}")


def _mlp(in_features: int, hidden: int, layers: int) -> torch.nn.Sequential:
    """``layers`` hidden ReLU layers of width ``hidden``, then a linear layer to 3 outputs."""
    modules: list[torch.nn.Module] = []
    width = in_features
    for _ in range(layers):
        modules += [torch.nn.Linear(width, hidden), torch.nn.ReLU()]
        width = hidden
    modules.append(torch.nn.Linear(width, 3))
    return torch.nn.Sequential(*modules)


def predict(model: torch.nn.Module, kind: str, normals: torch.Tensor, v: torch.Tensor):
    """Predicted reflections ``[N, 3]`` of rays ``v`` ``[N, 3]`` at walls with ``normals``
    ``[N, 3]``, fed to ``model`` as representation ``kind``."""
    with torch.no_grad():
        return model(torch.cat([represent(normals, kind), v], dim=1))


def train_representation(
    kind: str,
    data: dict[str, torch.Tensor],
    *,
    seed: int,
    steps: int,
    batch_size: int,
    hidden: int,
    layers: int,
    lr: float,
    bar: tqdm | None = None,
) -> torch.nn.Module:
    """Train an MLP on ``data`` (from :func:`make_reflection_data`) with representation ``kind``.

    Plain Adam on the mean squared error; each step draws ``batch_size`` rays with replacement.
    Initialisation and batches depend only on ``seed`` (the global torch RNG is left as is).

    Args:
        kind: ``"R1"`` .. ``"R4"``.
        data: training rays (``normals``, ``incident``, ``reflected``; ``[N, 3]`` each).
        seed: random seed of the initialisation and the batches.
        steps: optimiser steps.
        batch_size: rays per step.
        hidden: width of each hidden layer.
        layers: number of hidden layers.
        lr: Adam learning rate.
        bar: tqdm bar advanced by one per step (optional).

    Returns:
        The trained model in eval mode: ``[N, width(kind) + 3] -> [N, 3]``.
    """
    x = torch.cat([represent(data["normals"], kind), data["incident"]], dim=1)
    y = data["reflected"]
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = _mlp(x.shape[1], hidden, layers).to(x.dtype)
    gen = torch.Generator().manual_seed(seed)
    optimiser = torch.optim.Adam(model.parameters(), lr=lr)
    chunk = 0
    for _ in range(steps):
        idx = torch.randint(len(x), (batch_size,), generator=gen)
        loss = torch.nn.functional.mse_loss(model(x[idx]), y[idx])
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        chunk += 1
        if bar is not None and chunk == 100:
            bar.update(chunk)
            chunk = 0
    if bar is not None and chunk:
        bar.update(chunk)
    return model.eval()


def check_config(cfg: DictConfig | dict) -> dict[str, Any]:
    """Validate the experiment's config; returns it as a plain dict.

    Raises:
        InputError: naming the bad key and how to fix it.
    """
    plain: dict[str, Any] = {}
    for key in ("seeds", "representations", *_POSITIVE_INTS, "lr", "progress"):
        if key not in cfg or cfg[key] is None:
            raise InputError(f"{key}: missing from the config; add it (see conf/reflection.yaml)")
        value = cfg[key]
        plain[key] = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
    for key, example in _POSITIVE_INTS.items():
        value = plain[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InputError(
                f"{key}: expected a positive integer, got {value!r}; e.g. {key}={example}"
            )
    if plain["train_samples"] < len(WALLS):
        raise InputError(
            f"train_samples: need at least one ray per wall ({len(WALLS)}), "
            f"got {plain['train_samples']}; e.g. train_samples=4096"
        )
    seeds = plain["seeds"]
    if (
        not isinstance(seeds, list)
        or not seeds
        or any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in seeds)
    ):
        raise InputError(
            f"seeds: expected a non-empty list of non-negative integers, got {seeds!r}; "
            "e.g. seeds=[0,1,2]"
        )
    reps = plain["representations"]
    if (
        not isinstance(reps, list)
        or not reps
        or any(r not in KINDS for r in reps)
        or len(set(reps)) != len(reps)
    ):
        raise InputError(
            f"representations: expected distinct names from {list(KINDS)}, got {reps!r}; "
            "e.g. representations=[R1,R2,R3,R4]"
        )
    lr = plain["lr"]
    if isinstance(lr, bool) or not isinstance(lr, int | float) or not (0 < lr < math.inf):
        raise InputError(f"lr: expected a positive learning rate, got {lr!r}; e.g. lr=0.001")
    plain["lr"] = float(lr)
    if not isinstance(plain["progress"], bool):
        raise InputError(f"progress: expected true or false, got {plain['progress']!r}")
    try:
        out = cfg.get("out")
    except OmegaConfBaseException as exc:  # ${hydra:...} outside a Hydra app
        raise InputError(
            f"out: cannot be resolved here ({type(exc).__name__}); pass out=<folder> or out=null"
        ) from exc
    plain["out"] = None if out is None else str(out)
    return plain


def _stats(values: list[float]) -> dict[str, Any]:
    """Mean and sample standard deviation (0 for a single value) over seeds."""
    arr = np.asarray(values, dtype=np.float64)
    std = float(arr.std(ddof=1)) if len(arr) > 1 else 0.0
    return {"mean": float(arr.mean()), "std": std, "per_seed": [float(v) for v in arr]}


def run_experiment(cfg: DictConfig | dict, command: str | None = None) -> dict[str, Any]:
    """Train and evaluate every representation for every seed; write the outputs to ``cfg.out``.

    Errors are Euclidean distances between predicted and true reflections of unit rays (so in
    units of ``|v|``), averaged over the test rays, then mean and std over seeds. The same test
    rays are evaluated with the training normals (``same``) and with ``-n`` (``inverted``).

    Args:
        cfg: see ``conf/reflection.yaml``; ``out=null`` writes nothing.
        command: the command line recorded in ``results.json``.

    Returns:
        ``{"representations": {kind: {"features", "same": {"mean", "std", "per_seed"},
        "inverted": {...}}}, "seeds", "config", "wall_time_s", "files", ...}``.

    Raises:
        InputError: for a bad config value.
    """
    p = check_config(cfg)
    threads = torch.get_num_threads()
    torch.set_num_threads(p["threads"])
    try:
        start = time.perf_counter()
        errors, first_models = _train_and_evaluate(p)
        results = _summarise(p, errors, time.perf_counter() - start)
        if p["out"] is not None:
            results["files"] = _write_outputs(Path(p["out"]), results, first_models, p, command)
    finally:
        torch.set_num_threads(threads)
    return results


def _train_and_evaluate(
    p: dict[str, Any],
) -> tuple[dict[str, dict[str, list[float]]], dict[str, torch.nn.Module]]:
    """Per representation, the test errors per seed (``same``, ``inverted``), and the models
    of the first seed (for the figures)."""
    errors: dict[str, dict[str, list[float]]] = {
        k: {"same": [], "inverted": []} for k in p["representations"]
    }
    first_models: dict[str, torch.nn.Module] = {}
    total = len(p["seeds"]) * len(p["representations"]) * p["steps"]
    with tqdm(
        total=total, desc="reflection", unit="step", disable=not show_progress(p["progress"])
    ) as bar:
        for seed in p["seeds"]:
            gen = torch.Generator().manual_seed(seed)
            train = make_reflection_data(p["train_samples"], gen)
            test = make_reflection_data(p["test_samples"], gen)
            for kind in p["representations"]:
                bar.set_postfix_str(f"{kind} seed {seed}")
                model = train_representation(
                    kind,
                    train,
                    seed=seed,
                    steps=p["steps"],
                    batch_size=p["batch_size"],
                    hidden=p["hidden"],
                    layers=p["layers"],
                    lr=p["lr"],
                    bar=bar,
                )
                for case, normals in (("same", test["normals"]), ("inverted", -test["normals"])):
                    pred = predict(model, kind, normals, test["incident"])
                    truth = reflect(test["incident"], normals)
                    err = torch.linalg.vector_norm(pred - truth, dim=1).mean()
                    errors[kind][case].append(float(err))
                if seed == p["seeds"][0]:
                    first_models[kind] = model
    return errors, first_models


def _summarise(
    p: dict[str, Any], errors: dict[str, dict[str, list[float]]], wall_time_s: float
) -> dict[str, Any]:
    """The results dict (without files) from the per-seed errors."""
    return {
        "experiment": "reflection (paper Appendix B.1)",
        "error": "mean |predicted - true reflection| over test rays (|v| = 1); std over seeds",
        "seeds": p["seeds"],
        "representations": {
            kind: {
                "features": KINDS[kind][1],
                "same": _stats(errors[kind]["same"]),
                "inverted": _stats(errors[kind]["inverted"]),
            }
            for kind in p["representations"]
        },
        "config": {k: v for k, v in p.items() if k != "out"},
        "wall_time_s": wall_time_s,
    }


def format_table(results: dict[str, Any]) -> str:
    """Markdown table: error mean ± std per representation, same vs inverted normals."""
    n = len(results["seeds"])
    columns = [
        "representation",
        "wall features",
        f"same normals: error (n={n} seeds)",
        f"inverted normals: error (n={n} seeds)",
    ]
    cells = [
        [
            kind,
            f"`{row['features']}`",
            f"{row['same']['mean']:.4f} ± {row['same']['std']:.4f}",
            f"{row['inverted']['mean']:.4f} ± {row['inverted']['std']:.4f}",
        ]
        for kind, row in results["representations"].items()
    ]
    return markdown_table(columns, cells)


def _write_outputs(
    out: Path,
    results: dict[str, Any],
    models: dict[str, torch.nn.Module],
    p: dict[str, Any],
    command: str | None,
) -> dict[str, str]:
    """Write results.json, table.md, table.csv and the two figures; returns their paths."""
    from granular_pyg.bench.report import git_commit, machine_info, versions

    files = {
        "results": out / "results.json",
        "table_md": out / "table.md",
        "table_csv": out / "table.csv",
        "figure_same": out / "figures" / "reflection_same.png",
        "figure_inverted": out / "figures" / "reflection_inverted.png",
    }
    for key, inverted in (("figure_same", False), ("figure_inverted", True)):
        fig = reflection_figure(models, inverted, p["figure_rays"], results["representations"])
        FigureCanvasAgg(fig)
        with atomic_write(files[key], "wb") as fh:
            fig.savefig(fh, format="png", dpi=120, bbox_inches="tight")

    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(
        [
            *("representation", "features", "same_mean", "same_std"),
            *("inverted_mean", "inverted_std", "seeds"),
        ]
    )
    for kind, row in results["representations"].items():
        same, inv = row["same"], row["inverted"]
        n_seeds = len(results["seeds"])
        writer.writerow(
            [kind, row["features"], same["mean"], same["std"], inv["mean"], inv["std"], n_seeds]
        )
    with atomic_write(files["table_csv"]) as fh:
        fh.write(buf.getvalue())

    table = format_table(results)
    text = [
        "# Reflection toy experiment (paper Appendix B.1)",
        "",
        f"Error: {results['error']}. Seeds: {results['seeds']}. "
        f"Wall time: {results['wall_time_s']:.1f} s.",
        "",
        table,
        "",
        "![same normals](figures/reflection_same.png)",
        "",
        "![inverted normals](figures/reflection_inverted.png)",
        "",
    ]
    with atomic_write(files["table_md"]) as fh:
        fh.write("\n".join(text))

    payload = dict(results)
    payload["files"] = {k: str(v) for k, v in files.items()}
    payload["machine"] = machine_info()
    payload["versions"] = versions()
    payload["commit"] = git_commit()
    payload["command"] = command
    with atomic_write(files["results"]) as fh:
        json.dump(payload, fh, indent=2)
    return payload["files"]


def figure_rays(per_wall: int, dtype: torch.dtype = torch.float32) -> dict[str, torch.Tensor]:
    """In-plane (``y = 0``) rays for the figures: ``per_wall`` per wall, hitting it at evenly
    spaced points and inclined by up to 40° from the normal, travelling into the wall.

    Returns:
        ``{"wall": [M], "normals": [M, 3], "incident": [M, 3] unit rays, "hit": [M, 3] points
        on the walls of the cube [-1, 1]^3}`` with ``M = 4 * per_wall``.
    """
    offsets = torch.linspace(-0.5, 0.5, per_wall, dtype=dtype)
    angles = offsets / 0.5 * math.radians(40.0)
    wall = torch.arange(len(WALLS)).repeat_interleave(per_wall)
    normals = wall_normals(dtype)[wall]
    # In-plane tangent: the normal turned by 90° about y.
    tangent = torch.stack([normals[:, 2], torch.zeros_like(wall, dtype=dtype), -normals[:, 0]], 1)
    s, a = offsets.repeat(len(WALLS)).unsqueeze(1), angles.repeat(len(WALLS)).unsqueeze(1)
    incident = torch.cos(a) * normals + torch.sin(a) * tangent
    return {"wall": wall, "normals": normals, "incident": incident, "hit": normals + s * tangent}


def reflection_figure(
    models: dict[str, torch.nn.Module],
    inverted: bool,
    per_wall: int = 3,
    summary: dict[str, Any] | None = None,
) -> Figure:
    """The paper's Figure B.1 (``inverted=False``) or B.2 (``inverted=True``): rays reflected at
    the four walls (x-z plane), ground truth and one panel per representation.

    Args:
        models: trained model per representation (``"R1"`` .. ``"R4"``).
        inverted: feed ``-n`` instead of the training normals.
        per_wall: rays per wall.
        summary: ``results["representations"]`` to print the error in each panel's title.

    Returns:
        A matplotlib ``Figure`` (no pyplot state; the caller saves it).
    """
    rays = figure_rays(per_wall)
    normals = -rays["normals"] if inverted else rays["normals"]
    v, hit = rays["incident"], rays["hit"]
    truth = reflect(v, normals)
    panels = ["truth", *models]
    rows = (len(panels) + 2) // 2  # the legend takes the second cell of the first row
    fig = Figure(figsize=(9, 4.0 * rows), layout="constrained")
    axes = fig.subplots(rows, 2).reshape(-1)
    cells = [axes[0], *axes[2:]]
    length = 0.4
    xz = [0, 2]
    centres = wall_normals()[:, xz].numpy()
    shown_n = (-wall_normals() if inverted else wall_normals())[:, xz].numpy()
    hit2, v2, truth2 = hit[:, xz].numpy(), v[:, xz].numpy(), truth[:, xz].numpy()
    for ax, name in zip(cells, panels, strict=False):
        ax.plot([-1, 1, 1, -1, -1], [-1, -1, 1, 1, -1], color="0.5", lw=1.5)
        ax.quiver(*centres.T, *(0.35 * shown_n).T, **_arrows("black"))
        start = hit2 - length * v2
        ax.quiver(*start.T, *(length * v2).T, **_arrows("tab:blue"))
        if name == "truth":
            ax.quiver(*hit2.T, *(length * truth2).T, **_arrows("tab:green"))
            title = _TITLES[inverted]["truth"]
        else:
            pred = predict(models[name], name, normals, v)[:, xz].numpy()
            ax.quiver(*hit2.T, *(length * truth2).T, **_arrows("tab:green", alpha=0.3))
            ax.quiver(*hit2.T, *(length * pred).T, **_arrows("tab:red"))
            title = _TITLES[inverted][name]
            if summary is not None and name in summary:
                s = summary[name]["inverted" if inverted else "same"]
                title += f"\nerror {s['mean']:.3f} ± {s['std']:.3f}"
        ax.set_title(title, fontsize=10)
        ax.set_xlim(-1.6, 1.6)
        ax.set_ylim(-1.6, 1.6)
        ax.set_aspect("equal")
        ax.set_axis_off()
    for ax in axes[len(panels) + 1 :]:
        ax.axis("off")
    legend = axes[1]
    legend.axis("off")
    handles = [
        Line2D([], [], color=c, lw=2.5, label=label)
        for c, label in (
            ("black", "Wall normal vectors"),
            ("tab:blue", "Incident rays"),
            ("tab:green", "True reflected rays"),
            ("tab:red", "Predicted reflected rays"),
        )
    ]
    legend.legend(handles=handles, loc="center", frameon=False, fontsize=11)
    which = "inversely oriented to" if inverted else "oriented as in"
    fig.suptitle(f"Reflection at four walls (x-z plane); wall normals {which} training")
    return fig


def _arrows(colour: str, alpha: float = 1.0) -> dict[str, Any]:
    """quiver arguments for arrows drawn exactly in data units."""
    return {
        "angles": "xy",
        "scale_units": "xy",
        "scale": 1.0,
        "color": colour,
        "alpha": alpha,
        "width": 0.009,
    }


@command("reflection")
def main(cfg: DictConfig) -> None:
    results = run_experiment(cfg, command=command_line("granular_pyg.experiments.reflection"))
    print(format_table(results))
    print(f"wall time: {results['wall_time_s']:.1f} s ({len(results['seeds'])} seeds)")
    print(f"output: {cfg.out}")


if __name__ == "__main__":
    main()
