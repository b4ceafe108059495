"""The radius_graph suite: both backends timed on the same points, their edges compared."""

from __future__ import annotations

import pytest

from granular_pyg.bench.radius_graph import run
from granular_pyg.config import compose


def test_the_suite_times_both_backends_and_checks_their_edges():
    pytest.importorskip("torch_cluster")
    result = run(num_points=(300,), repeats=1)
    assert [t.met for t in result.targets] == [True]
    assert set(result.results) == {"300/scipy_s", "300/torch_cluster_s", "300/query_pairs_s"}
    assert "scipy (ms)" in result.notes


def test_it_is_a_bench_suite():
    cfg = compose("bench", ["suite=radius_graph", "threads=1"])
    assert cfg.suite.run._target_ == "granular_pyg.bench.radius_graph.run"
