"""The bench has one thread setting: ``threads`` of ``conf/bench.yaml`` reaches every suite that
runs torch (their own ``threads`` keys follow it, the scaling suite's child processes too)."""

from __future__ import annotations

import inspect

import pytest
from omegaconf import OmegaConf

from granular_pyg.config import CONF_DIR, compose

SUITES = sorted(p.stem for p in (CONF_DIR / "suite").glob("*.yaml"))


@pytest.mark.parametrize("suite", SUITES)
def test_every_suite_follows_the_benchs_one_threads_setting(suite):
    cfg = compose("bench", [f"suite={suite}", "threads=1"])
    run = OmegaConf.to_container(cfg.suite.run, resolve=True)
    assert run.get("threads", 1) == 1, f"suite {suite} keeps its own thread count"
    raw = OmegaConf.load(CONF_DIR / "suite" / f"{suite}.yaml")
    if "threads" in raw.run:
        assert OmegaConf.to_container(raw.run)["threads"] == "${threads}"


def test_the_scaling_suites_children_get_the_benchs_threads():
    from granular_pyg.bench import scaling

    assert "threads" in inspect.signature(scaling._measure).parameters
    assert "set_num_threads(2)" not in inspect.getsource(scaling)
