"""``python -m granular_pyg.experiments.fine_tune_curve``: how quickly a trained model adapts to a
geometry family it never saw. It is fine-tuned on 1, 2 and 5 of the family's trajectories for
10, 30 and 60 minutes of training, and each result is scored on the family's trajectories
that none of the runs trained on::

    python -m granular_pyg.experiments.fine_tune_curve --init pretrained:hopper \\
        --family data/hoppers/cone --new 1 2 5 --minutes 10 30 60 --out outputs/fine_tune_curve

Each run is ``python -m granular_pyg.train +experiment=finetune init=<init>`` with an explicit
training list: the first ``n`` trajectories of the family's ``train`` split. It trains to the
first budget, is evaluated, and is resumed from its checkpoint (Lightning's timer included) to
the next budget. The minutes are training wall time on one thread. The scored set is the
family's ``test`` split plus the ``train`` trajectories beyond the largest ``n``. The initial
model, scored on the same set, is the curve's point at 0 trajectories.

Writes ``curve.json`` (every point's mean and worst discharge-rate error, leaks, crushed
particles and steps), ``curve.md`` (the table and the command) and ``curve.png``. Points that
are already evaluated are read back, so a stopped curve continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from granular_pyg.checkpoint import resolve_checkpoint, safe_load
from granular_pyg.cli import reports_errors
from granular_pyg.data import load_split
from granular_pyg.errors import InputError, whole_number
from granular_pyg.io import atomic_write
from granular_pyg.io.markdown import command_header, markdown_table

__all__ = ["fine_tune_curve", "split_family"]

#: Scalars of each evaluation kept on the curve (mean over the scored set; ``worst`` of the first).
KEPT = (
    "discharge_rate_rel_error",
    "leaked_particles",
    "crushed_particles",
    "crushed_particles_truth",
)


def split_family(family: Path, largest: int) -> tuple[list[Path], list[Path], list[Path]]:
    """``(pool, valid, scored)`` of a family folder: its ``train`` trajectories (the first
    ``n`` train a run), its ``valid`` split, and the trajectories no run trains on."""
    train, valid = load_split(family, None, "train"), load_split(family, None, "valid")
    if len(train) < largest:
        raise InputError(
            f"--new: {family} has {len(train)} training trajectories, fewer than {largest}"
        )
    scored = load_split(family, None, "test") + train[largest:]
    if not scored:
        raise InputError(f"--family: {family} leaves no trajectory to score; it needs more")
    return train[:largest], valid, scored


def _run(args: list[str]) -> None:
    print("$ " + " ".join(args), flush=True)
    done = subprocess.run([sys.executable, "-m", *args])
    if done.returncode != 0:
        raise InputError(f"{args[0]} stopped with status {done.returncode}; see its output above")


def _evaluate(ckpt: Path, scored: list[Path], out: Path, threads: int) -> dict:
    """The curve point of ``ckpt`` on ``scored`` (evaluated once, then read back)."""
    summary = out / "evaluation.json"
    if not summary.is_file():
        listed = ",".join(str(p) for p in scored)
        _run(
            [
                "granular_pyg.evaluate",
                f"ckpt={ckpt}",
                f"trajectories=[{listed}]",
                f"hydra.run.dir={out}",
                "paraview=0",
                "progress=false",
                f"threads={threads}",
            ]
        )
    rows = json.loads(summary.read_text())["trajectories"]
    # None: a metric that does not apply (a clogged truth has no discharge rate to miss)
    rows = [{k: np.nan if v is None else v for k, v in r.items()} for r in rows]
    point = {key: float(np.nanmean([r[key] for r in rows])) for key in KEPT}
    errors = [abs(r["discharge_rate_rel_error"]) for r in rows]
    point["discharge_rate_abs_error_mean"] = float(np.nanmean(errors))
    point["discharge_rate_abs_error_worst"] = float(np.nanmax(errors))
    point["scored"] = len(rows)
    return point


def _train(
    init: str,
    pool: list[Path],
    valid: list[Path],
    minutes: int,
    run: Path,
    threads: int,
    overrides: list[str],
) -> Path:
    """Train (or resume) ``run`` to ``minutes`` of training time; returns its checkpoint."""
    last = run / "checkpoints" / "last.ckpt"
    args = [
        "granular_pyg.train",
        "+experiment=finetune",
        f"init={init}",
        "data.root=null",
        f"+data.trajectories={{train: [{','.join(map(str, pool))}], "
        f"valid: [{','.join(map(str, valid))}]}}",
        f"trainer.max_time=00:00:{minutes:02d}:00"
        if minutes < 60
        else f"trainer.max_time=00:{minutes // 60:02d}:{minutes % 60:02d}:00",
        f"hydra.run.dir={run}",
        f"threads={threads}",
        "checkpoint.every_n_train_steps=20",
        *overrides,
    ]
    if last.is_file():
        args.append(f"ckpt_path={last}")
    _run(args)
    return last


def fine_tune_curve(
    init: str,
    family: Path,
    new: list[int],
    minutes: list[int],
    out: Path,
    threads: int = 1,
    overrides: list[str] | None = None,
    pool_size: int | None = None,
) -> dict:
    """Run (or continue) the curve; returns it (also written to ``out/curve.json``).
    ``pool_size``: training trajectories set aside for the runs (default the largest of
    ``new``); the rest are scored, so calls that run parts of one curve must agree on it."""
    new, minutes = sorted(set(new)), sorted(set(minutes))
    pool, valid, scored = split_family(family, max(max(new), pool_size or 0))
    curve = {
        "init": init,
        "family": str(family),
        "scored": [str(p) for p in scored],
        "points": [{"new": 0, "minutes": 0, **_evaluate_init(init, scored, out, threads)}],
    }
    for n in new:
        run = out / f"new{n}"
        for budget in minutes:
            snapshot = run / f"at_{budget}min.ckpt"
            if not snapshot.is_file():
                ckpt = _train(init, pool[:n], valid, budget, run, threads, overrides or [])
                with atomic_write(snapshot, "wb") as fh:
                    fh.write(ckpt.read_bytes())
            point = _evaluate(snapshot, scored, run / f"evaluate_{budget}min", threads)
            steps = int(safe_load(snapshot, "snapshot")["global_step"])
            curve["points"].append({"new": n, "minutes": budget, "steps": steps, **point})
            _write(curve, out)
    _write(curve, out)
    return curve


def _evaluate_init(init: str, scored: list[Path], out: Path, threads: int) -> dict:
    return _evaluate(resolve_checkpoint(init), scored, out / "evaluate_initial", threads)


def _write(curve: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "curve.json") as fh:
        json.dump(curve, fh, indent=1)
    rows = [
        [
            p["new"],
            p["minutes"],
            p.get("steps", 0),
            f"{100 * p['discharge_rate_abs_error_mean']:.1f}%",
            f"{100 * p['discharge_rate_abs_error_worst']:.1f}%",
            f"{p['leaked_particles']:.0f}",
            f"{p['crushed_particles']:.0f} ({p['crushed_particles_truth']:.0f})",
        ]
        for p in curve["points"]
    ]
    table = markdown_table(
        [
            "new trajectories",
            "training minutes",
            "steps",
            "discharge-rate error, mean",
            "worst",
            "leaked (mean)",
            "crushed (LIGGGHTS)",
        ],
        rows,
    )
    header = command_header("granular_pyg.experiments.fine_tune_curve")
    text = (
        f"# Fine-tuning {curve['init']} on {curve['family']}\n\n{header}\n\n"
        f"Scored on {len(curve['scored'])} trajectories no run trained on.\n\n{table}\n"
    )
    with atomic_write(out / "curve.md") as fh:
        fh.write(text)
    _plot(curve, out / "curve.png")


def _plot(curve: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    start = curve["points"][0]["discharge_rate_abs_error_mean"] * 100
    for n in sorted({p["new"] for p in curve["points"] if p["new"]}):
        pts = [p for p in curve["points"] if p["new"] == n]
        ax.plot(
            [0] + [p["minutes"] for p in pts],
            [start] + [100 * p["discharge_rate_abs_error_mean"] for p in pts],
            marker="o",
            label=f"{n} new trajectories",
        )
    ax.axhline(5, color="grey", lw=0.8, ls="--", label="5% target")
    ax.set_xlabel("training minutes (one core)")
    ax.set_ylabel("discharge-rate error, mean (%)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=120)
    plt.close(fig)


@reports_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--init", default="pretrained:hopper")
    parser.add_argument("--family", required=True, type=Path, help="a family's dataset folder")
    parser.add_argument("--new", type=int, nargs="+", default=[1, 2, 5])
    parser.add_argument("--minutes", type=int, nargs="+", default=[10, 30, 60])
    parser.add_argument("--out", type=Path, default=Path("outputs/fine_tune_curve"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--pool",
        type=int,
        default=None,
        help="training trajectories set aside (default: the largest --new); the rest are scored",
    )
    parser.add_argument("overrides", nargs="*", help="extra train overrides (key=value)")
    args = parser.parse_args(argv)
    for n in args.new:
        whole_number("--new", n, minimum=1)
    for m in args.minutes:
        whole_number("--minutes", m, minimum=1)
    curve = fine_tune_curve(
        args.init,
        args.family,
        args.new,
        args.minutes,
        args.out,
        args.threads,
        args.overrides,
        args.pool,
    )
    print(f"curve: {args.out / 'curve.md'} ({len(curve['points'])} points)")


if __name__ == "__main__":
    main()
