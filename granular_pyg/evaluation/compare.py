"""The paper's variant table: EMD mean and std per variant, train and test, with paired
Wilcoxon tests against a reference variant (V3)."""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.stats import wilcoxon

from granular_pyg.errors import InputError
from granular_pyg.io import markdown_table

__all__ = ["load_emd_values", "variant_table", "write_variant_figures"]

#: Normal variant of a model config -> the paper's name.
VARIANTS = {"none": "V1", "single": "V2", "both": "V3"}


def load_emd_values(run: str | Path) -> tuple[str, dict[tuple[str, str, int], float]]:
    """An evaluation folder's variant name and its EMD values keyed ``(split, traj, step)``."""
    run = Path(run)
    summary, table = run / "evaluation.json", run / "emd_steps.csv"
    if not summary.is_file() or not table.is_file():
        raise InputError(
            f"{run}: not an evaluation folder (needs evaluation.json and emd_steps.csv); "
            "make one with `python -m granular_pyg.evaluate ckpt=...`"
        )
    variant = json.loads(summary.read_text())["variant"]
    with table.open() as fh:
        values = {
            (row["split"], row["trajectory"], int(row["step"])): float(row["emd"])
            for row in csv.DictReader(fh)
        }
    return variant, values


def variant_table(runs: list[str | Path], reference: str = "V3") -> tuple[list[dict], str]:
    """EMD statistics per variant and split, and paired Wilcoxon p-values against ``reference``.

    Runs of the same variant (several seeds) are averaged per ``(split, trajectory, step)``
    first. Each variant's values are then paired with the reference's on the keys both have
    (the trajectories concatenated, as the paper does) and tested with
    ``scipy.stats.wilcoxon``: ``p(ref < row)`` is the one-sided p-value of the hypothesis that
    the reference's EMD is smaller (the paper's "V3 significantly outperforms V1"),
    ``p(row < ref)`` the opposite direction.

    Args:
        runs: evaluation folders (``python -m granular_pyg.evaluate``).
        reference: the variant every row is tested against.

    Returns:
        ``(rows, markdown)``: one dict per variant (``variant, runs, <split>_mu,
        <split>_sigma, <split>_n, <split>_p_ref_less, <split>_p_row_less``) and the table.
    """
    if not runs:
        raise InputError("runs: give at least one evaluation folder, e.g. runs=[a,b]")
    grouped: dict[str, list[dict]] = defaultdict(list)
    for run in runs:
        variant, values = load_emd_values(run)
        grouped[variant].append(values)
    if reference not in grouped:
        raise InputError(f"reference: no run of variant {reference!r} (have {sorted(grouped)})")
    means = {v: _mean_over_seeds(vals) for v, vals in grouped.items()}
    splits = sorted({key[0] for vals in means.values() for key in vals})
    rows = []
    for variant in sorted(means):
        row: dict = {"variant": variant, "runs": len(grouped[variant])}
        for split in splits:
            values = {k: v for k, v in means[variant].items() if k[0] == split}
            arr = np.array(list(values.values()))
            row[f"{split}_mu"] = float(arr.mean()) if len(arr) else float("nan")
            row[f"{split}_sigma"] = float(arr.std()) if len(arr) else float("nan")
            row[f"{split}_n"] = len(arr)
            ref = {k: v for k, v in means[reference].items() if k[0] == split}
            keys = sorted(set(values) & set(ref))
            p_ref, p_row = float("nan"), float("nan")
            if variant != reference and len(keys) >= 2:
                diff = np.array([ref[k] - values[k] for k in keys])
                if np.any(diff != 0):
                    p_ref = float(wilcoxon(diff, alternative="less").pvalue)
                    p_row = float(wilcoxon(-diff, alternative="less").pvalue)
            row[f"{split}_p_ref_less"], row[f"{split}_p_row_less"] = p_ref, p_row
        rows.append(row)
    return rows, _markdown(rows, splits, reference)


def write_variant_figures(runs: list[str | Path], out_dir: str | Path, split: str = "test"):
    """The paper's Figure 2 for each ``split`` trajectory that every variant has: the ground
    truth against the rollout of each variant's first run (in the order given, so seed 0 when
    the runs are listed by seed). Writes ``figures/variants_<split>_<trajectory>.png``.

    Args:
        runs: evaluation folders (``python -m granular_pyg.evaluate``), whose
            ``evaluation.json`` name the truth and rollout file of every trajectory.
        out_dir: folder that gets ``figures/``.
        split: the split whose trajectories are drawn.

    Returns:
        The written PNG paths, one per trajectory every variant has (none if no run is given).
    """
    from granular_pyg.evaluation.figures import variants_figure
    from granular_pyg.evaluation.pair import evaluate_pair
    from granular_pyg.io import atomic_path, read_trajectory

    first: dict[str, dict[str, dict]] = {}
    for run in runs:
        summary = json.loads((Path(run) / "evaluation.json").read_text())
        if summary["variant"] in first:
            continue
        first[summary["variant"]] = {
            t["name"]: t for t in summary["trajectories"] if t["split"] == split
        }
    common = sorted(set.intersection(*(set(v) for v in first.values()))) if first else []
    written = []
    for name in common:
        entries = {variant: first[variant][name] for variant in sorted(first)}
        truth = read_trajectory(next(iter(entries.values()))["truth"])
        evaluations = {
            v: evaluate_pair(truth, read_trajectory(e["prediction"])) for v, e in entries.items()
        }
        shown = "/".join(evaluations)
        fig = variants_figure(evaluations, f"{split} / {name}: LIGGGHTS (solid) vs {shown}")
        path = Path(out_dir) / "figures" / f"variants_{split}_{Path(name).stem}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=100, format="png")
        written.append(path)
    return written


def _mean_over_seeds(runs: list[dict]) -> dict:
    keys = set.intersection(*(set(r) for r in runs))
    return {k: float(np.mean([r[k] for r in runs])) for k in keys}


def _markdown(rows: list[dict], splits: list[str], reference: str) -> str:
    columns = ["variant", "runs"]
    for split in splits:
        columns += [
            f"{split} mu",
            f"{split} sigma",
            f"{split} p ({reference} < row)",
            f"{split} p (row < {reference})",
        ]
    cells = []
    for row in rows:
        line = [row["variant"], row["runs"]]
        for split in splits:
            line += [
                f"{row[f'{split}_mu']:.3e}",
                f"{row[f'{split}_sigma']:.3e}",
                _p(row[f"{split}_p_ref_less"]),
                _p(row[f"{split}_p_row_less"]),
            ]
        cells.append(line)
    return markdown_table(columns, cells) + "\n"


def _p(value: float) -> str:
    return "" if np.isnan(value) else f"{value:.2e}"
