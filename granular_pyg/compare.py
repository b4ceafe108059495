"""``python -m granular_pyg.compare 'runs=[...]'``: the paper's variant table (EMD mu and sigma
per variant, train and test, paired Wilcoxon p-values against V3) as Markdown and CSV, and the
paper's Figure 2 (the truth against each variant) for every test trajectory."""

from __future__ import annotations

import csv
from pathlib import Path

from omegaconf import DictConfig

from granular_pyg.cli import command
from granular_pyg.evaluation import variant_table
from granular_pyg.evaluation.compare import write_variant_figures
from granular_pyg.io import atomic_write

__all__ = ["compare"]


def compare(cfg: DictConfig) -> Path:
    """Build the table of ``cfg.runs``; returns the path of ``table.md`` (``table.csv`` beside)."""
    rows, markdown = variant_table(list(cfg.runs), cfg.reference)
    out = Path(cfg.out)
    with atomic_write(out / "table.md") as fh:
        fh.write(markdown)
    with atomic_write(out / "table.csv") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(markdown)
    print(f"table: {out / 'table.md'}")
    if cfg.get("figures", True):
        for path in write_variant_figures(list(cfg.runs), out, cfg.get("figure_split", "test")):
            print(f"figure: {path}")
    return out / "table.md"


@command("compare")
def main(cfg: DictConfig) -> None:
    compare(cfg)


if __name__ == "__main__":
    main()
