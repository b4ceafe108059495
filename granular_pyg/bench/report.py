"""Shared benchmark plumbing: timing, machine description, and the files every suite writes.

Every suite writes, into its output folder: ``results.json`` (flat ``{name: number}`` plus
``machine``, ``versions``, ``commit`` and ``command``), ``results.csv`` (one row per
measurement), ``report.md`` (tables and targets) and ``results.png`` (the figure).
"""

from __future__ import annotations

import csv
import io
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from granular_pyg.io import atomic_write, markdown_table


@dataclass
class Target:
    """A performance target: ``value`` must satisfy ``value <op> bound``."""

    name: str
    value: float
    op: str  # "<=" or ">="
    bound: float

    @property
    def met(self) -> bool:
        return self.value <= self.bound if self.op == "<=" else self.value >= self.bound


@dataclass
class SuiteResult:
    """What a suite returns: table rows, headline numbers, targets and a figure."""

    rows: list[dict]
    results: dict[str, float]
    targets: list[Target] = field(default_factory=list)
    figure: object | None = None  # a matplotlib Figure
    notes: str = ""


def time_call(fn: Callable[[], object], repeats: int, warmup: int = 1) -> float:
    """Median wall time (s) of ``fn()`` over ``repeats`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def synchronize(device: str) -> None:
    """Wait for the queued work of ``device`` (CUDA runs asynchronously), so timings are whole."""
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()


def machine_info() -> dict[str, object]:
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }


def versions() -> dict[str, str]:
    import importlib.metadata as md

    found = {"python": sys.version.split()[0]}
    for pkg in ("torch", "torch-geometric", "torch-cluster", "scipy", "trimesh", "granular_pyg"):
        try:
            found[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            found[pkg] = "not installed"
    return found


def git_commit() -> str:
    root = Path(__file__).resolve().parents[2]
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha + ("-dirty" if dirty else "")


def _columns(rows: list[dict]) -> list[str]:
    """Every key of ``rows`` in first-seen order (suites mix row kinds)."""
    return list(dict.fromkeys(k for row in rows for k in row))


def _markdown_table(rows: list[dict]) -> str:
    if not rows:
        return ""
    keys = _columns(rows)
    return markdown_table(keys, [[row.get(k) for k in keys] for row in rows])


def write_report(out_dir: Path, suite: str, result: SuiteResult, command: str) -> Path:
    """Write results.json, results.csv, report.md and results.png into ``out_dir``.

    Returns:
        The path of ``report.md``.
    """
    out_dir = Path(out_dir)
    payload = dict(result.results)
    payload.update(
        {f"target/{t.name}/met": float(t.met) for t in result.targets},
    )
    payload["machine"] = machine_info()
    payload["versions"] = versions()
    payload["commit"] = git_commit()
    payload["command"] = command
    with atomic_write(out_dir / "results.json") as fh:
        json.dump(payload, fh, indent=2)

    buf = io.StringIO()
    if result.rows:
        writer = csv.DictWriter(buf, fieldnames=_columns(result.rows))
        writer.writeheader()
        writer.writerows(result.rows)
    with atomic_write(out_dir / "results.csv") as fh:
        fh.write(buf.getvalue())

    if result.figure is not None:
        with atomic_write(out_dir / "results.png", "wb") as fh:
            result.figure.savefig(fh, format="png", dpi=120, bbox_inches="tight")

    lines = [f"# Benchmark `{suite}`", "", f"Command: `{command}`", ""]
    lines += [f"Commit `{payload['commit']}`, machine: {payload['machine']}", ""]
    lines += [_markdown_table(result.rows), ""]
    if result.targets:
        targets = [
            [t.name, f"{t.value:.3g}", f"{t.op} {t.bound:g}", "yes" if t.met else "NO"]
            for t in result.targets
        ]
        lines += [
            "## Targets",
            "",
            markdown_table(["target", "measured", "required", "met"], targets),
        ]
        lines.append("")
    if result.notes:
        lines += [result.notes, ""]
    if result.figure is not None:
        lines += ["![results](results.png)", ""]
    with atomic_write(out_dir / "report.md") as fh:
        fh.write("\n".join(lines))
    return out_dir / "report.md"
