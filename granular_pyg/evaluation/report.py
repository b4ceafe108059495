"""An evaluation folder: metrics as JSON and CSV, figures as PNG, a Markdown report, and the
same scalars and figures in TensorBoard."""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from granular_pyg.evaluation.figures import comparison_figure, discharge_figure
from granular_pyg.evaluation.pair import PairEvaluation
from granular_pyg.io import atomic_write, markdown_table

__all__ = ["EvaluatedRollout", "distinct_names", "rollout_label", "write_evaluation"]

#: Scalars the report's table shows, with their units.
HEADLINE = {
    "emd_mean": "m^2",
    "emd_frames": "",
    "emd_final": "m^2",
    "position_mse": "m^2",
    "mean_position_error": "m",
    "mixing_entropy_error": "",
    "flow_profile_error": "m/s",
    "discharge_rate_truth": "kg/s",
    "discharge_rate_pred": "kg/s",
    "discharge_rate_rel_error": "",
    "beverloo_rate": "kg/s",
    "discharged_fraction_truth": "",
    "discharged_fraction_pred": "",
    "discharged_fraction_error": "",
    "time_to_empty_truth_s": "s",
    "time_to_empty_pred_s": "s",
    "angle_of_repose_truth_deg": "deg",
    "angle_of_repose_pred_deg": "deg",
    "angle_of_repose_error_deg": "deg",
    "angle_of_repose_curve_error_deg": "deg",
    "leaked_particles": "",
    "crushed_particles": "",
    "rollout_wall_s": "s",
}


def distinct_names(files: list[Path]) -> list[str]:
    """Each file's shortest trailing path that no other file of ``files`` ends in: the file
    name, or ``cone/traj_0011.h5`` where several families have a ``traj_0011.h5``."""
    parts = [Path(f).parts for f in files]
    names = []
    for own in parts:
        depth = 1
        while depth < len(own) and any(
            other != own and other[-depth:] == own[-depth:] for other in parts
        ):
            depth += 1
        names.append("/".join(own[-depth:]))
    return names


def rollout_label(split: str, name: str) -> str:
    """The file-name stem of a rollout and its figure: split ``test``, trajectory
    ``cone/traj_0011.h5`` -> ``test_cone-traj_0011``."""
    return f"{split}_{str(Path(name).with_suffix('')).replace('/', '-')}"


@dataclass
class EvaluatedRollout:
    """One evaluated rollout: its split, trajectory name, files and evaluation."""

    split: str
    name: str
    truth_file: str
    pred_file: str
    evaluation: PairEvaluation


def write_evaluation(out_dir: str | Path, rollouts: list[EvaluatedRollout], info: dict) -> Path:
    """Write the evaluation folder; returns the path of ``report.md``.

    Files: ``evaluation.json`` (``info``, per-split means and per-trajectory scalars),
    ``metrics.csv`` (one row per trajectory), ``emd_steps.csv`` (``split, trajectory, step,
    emd``: the input of ``python -m granular_pyg.compare``), ``figures/<split>_<name>.png``,
    ``report.md`` and ``tensorboard/`` event files.

    Args:
        out_dir: the folder (created).
        rollouts: the evaluated rollouts.
        info: run facts (``variant``, ``ckpt``, ``command``...); ``variant`` is required by
            ``compare``.
    """
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    splits = sorted({r.split for r in rollouts})
    means = {
        split: _means([r.evaluation.scalars for r in rollouts if r.split == split])
        for split in splits
    }
    summary = {
        **info,
        "means": means,
        "trajectories": [
            {
                "split": r.split,
                "name": r.name,
                "truth": r.truth_file,
                "prediction": r.pred_file,
                **r.evaluation.scalars,
                "emd_steps": {str(k): v for k, v in r.evaluation.emd_steps.items()},
            }
            for r in rollouts
        ],
    }
    with atomic_write(out / "evaluation.json") as fh:
        json.dump(_jsonable(summary), fh, indent=1)
    _write_csv(
        out / "metrics.csv",
        [{"split": r.split, "trajectory": r.name, **r.evaluation.scalars} for r in rollouts],
    )
    _write_csv(
        out / "emd_steps.csv",
        [
            {"split": r.split, "trajectory": r.name, "step": k, "emd": v}
            for r in rollouts
            for k, v in sorted(r.evaluation.emd_steps.items())
        ],
    )
    figures, discharge = {}, {}
    writer = _tensorboard(out)
    for i, r in enumerate(rollouts):
        fig = comparison_figure(r.evaluation, f"{r.split} / {r.name}: LIGGGHTS (solid) vs learned")
        path = out / "figures" / f"{rollout_label(r.split, r.name)}.png"
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        with atomic_write(path, "wb") as fh:
            fh.write(buf.getvalue())
        figures[(r.split, r.name)] = path
        if writer is not None:
            writer.add_figure(f"evaluation/{r.split}/{r.name}", fig, global_step=i)
        if "discharged_mass_truth" in r.evaluation.series:  # every hopper: its discharge curve
            fig = discharge_figure(r.evaluation, f"{r.split} / {r.name}")
            path = out / "figures" / f"{rollout_label(r.split, r.name)}_discharge.png"
            _save_png(fig, path)
            discharge[(r.split, r.name)] = path
            if writer is not None:
                writer.add_figure(f"discharge/{r.split}/{r.name}", fig, global_step=i)
    if writer is not None:
        for split, values in means.items():
            for name, value in values.items():
                if math.isfinite(value):
                    writer.add_scalar(f"evaluation/{split}/{name}", value, 0)
        writer.close()
    report = out / "report.md"
    with atomic_write(report) as fh:
        fh.write(_markdown(rollouts, means, info, figures, out, discharge))
    return report


def _save_png(fig, path: Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    with atomic_write(path, "wb") as fh:
        fh.write(buf.getvalue())


def _means(rows: list[dict[str, float]]) -> dict[str, float]:
    keys = sorted({k for row in rows for k in row})
    out = {}
    for key in keys:
        vals = np.array([row.get(key, np.nan) for row in rows], dtype=float)
        out[key] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    return out


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _write_csv(path: Path, rows: list[dict]) -> None:
    fields = list(dict.fromkeys(k for row in rows for k in row))
    with atomic_write(path) as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


def _tensorboard(out: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is a dependency; stay usable without it
        return None
    return SummaryWriter(str(out / "tensorboard"))


def _fmt(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.3g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.2e}"


def _markdown(rollouts, means, info, figures, out: Path, discharge=None) -> str:
    lines = [
        "# Evaluation: learned rollouts against LIGGGHTS",
        "",
        f"- model: `{info.get('ckpt', '?')}` (variant {info.get('variant', '?')})",
        f"- command: `{info.get('command', '')}`",
        "- EMD: W2^2 (POT `ot.emd2` on squared Euclidean costs, uniform weights; above "
        "4,000 particles, over the same 4,000 particles drawn at random on both sides), at learned "
        "steps 2^k, every step the rollout has (`emd_frames` of them): where one side has "
        "drained and the other has not, the remaining particles' mean squared distance to the "
        "outlet point; errors are absolute differences of the curves, relative for the "
        "discharge rate.",
        "- discharge (hoppers): the initial bed is the particles above the outlet in the "
        "rollout's first frame, the same for both sides. `discharge_rate_*` is a line fitted to "
        "the mass of that bed that has left, from the moment 20% of it has left to the moment "
        "80% has (or to the rollout's end if it never does, so that a stall lowers the rate); "
        "`discharged_fraction_*` is the fraction of the bed gone at the rollout's end; "
        "`time_to_empty_*_s` the time from the outlet's opening until 99% of the bed has left "
        "(- : never within the rollout); `beverloo_rate` Beverloo's correlation for the scene's "
        "outlet (circle: 0.58 rho_b sqrt(g) (D - 1.5 d)^{5/2}; wall-to-wall slot: "
        "1.03 rho_b sqrt(g) L (b - 1.5 d)^{3/2}; rectangle: 1.03 rho_b sqrt(g) (L - 1.5 d) "
        "(b - 1.5 d)^{3/2}; rho_b = 0.6 x particle density, d the mean diameter), a reference, "
        "not the truth.",
        f"- rollout wall time: `rollout_wall_s`, the learned rollout alone "
        f"({info.get('threads', '?')} torch threads, {info.get('device', 'cpu')}).",
        "- leaked particles: centres that crossed a wall's triangle between two frames (walls "
        "posed at their times), lay outside the walls in their first frame, or left the "
        "simulation box other than through the outflow floor.",
        "",
        "## Means per split",
        "",
    ]
    shown = [k for k in HEADLINE if any(k in m for m in means.values())]
    lines.append(
        markdown_table(
            ["metric", "unit", *means],
            [
                [key, HEADLINE[key], *(_fmt(m.get(key, float("nan"))) for m in means.values())]
                for key in shown
            ],
        )
    )
    lines += ["", "## Per trajectory", ""]
    per_trajectory = []
    for r in rollouts:
        s = r.evaluation.scalars
        vals = [_fmt(s.get(k, float("nan"))) for k in shown]
        per_trajectory.append([r.split, r.name, int(s["steps"]), *vals])
    lines.append(markdown_table(["split", "trajectory", "steps", *shown], per_trajectory))
    lines += ["", "## Figures (LIGGGHTS solid, learned dashed)", ""]
    for (split, name), path in figures.items():
        lines.append(f"![{split} {name}]({path.relative_to(out)})")
    if discharge:
        lines += ["", "## Discharge curves (LIGGGHTS solid, learned dashed, Beverloo dotted)", ""]
        for (split, name), path in discharge.items():
            lines.append(f"![{split} {name} discharge]({path.relative_to(out)})")
    return "\n".join(lines) + "\n"
