"""``python -m granular_pyg.bench suite=<name>``: run one benchmark suite, write its report.

Outputs land in ``outputs/bench/<suite>/<timestamp>/`` (see ``conf/bench.yaml``).
"""

from __future__ import annotations

from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from granular_pyg.bench.report import SuiteResult, write_report
from granular_pyg.cli import command
from granular_pyg.io import command_line


@command("bench")
def main(cfg: DictConfig) -> dict[str, float]:
    torch.set_num_threads(cfg.threads)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    result: SuiteResult = hydra.utils.call(cfg.suite.run, repeats=cfg.repeats)
    report = write_report(out_dir, cfg.suite.name, result, command_line("granular_pyg.bench"))
    for key, value in result.results.items():
        print(f"{key:>48s}  {value:.4g}")
    for target in result.targets:
        status = "met" if target.met else "NOT MET"
        print(f"target {target.name}: {target.value:.3g} {target.op} {target.bound:g}  [{status}]")
    print(f"report: {report}")
    return result.results


if __name__ == "__main__":
    main()
