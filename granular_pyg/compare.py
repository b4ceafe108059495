"""``python -m granular_pyg.compare 'runs=[...]'``: the paper's variant table (EMD mu and sigma
per variant, train and test, paired Wilcoxon p-values against V3) as Markdown and CSV."""

from __future__ import annotations

import csv
from pathlib import Path

import hydra
from omegaconf import DictConfig

from granular_pyg.evaluation import variant_table
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
    return out / "table.md"


@hydra.main(version_base="1.3", config_path="../conf", config_name="compare")
def main(cfg: DictConfig) -> None:
    compare(cfg)


if __name__ == "__main__":
    main()
