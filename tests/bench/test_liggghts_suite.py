"""The `liggghts` suite end to end: LIGGGHTS rerun on the bundled hopper's Scene against the
shipped model's rollout, with and without the wall guard."""

from __future__ import annotations

import math

import pytest
import torch

from granular_pyg.bench.liggghts import run


def test_liggghts_suite_times_both_rollouts_and_judges_the_models_own():
    result = run("pretrained:hopper", mpi_procs=(1,), threads=1, wall_guard=True)
    names = [row["simulator"] for row in result.rows]
    assert names[0] == "LIGGGHTS, 1 MPI process"
    assert names[1].endswith("wall guard)") and not names[2].endswith("wall guard)")
    guarded, own = result.rows[1], result.rows[2]
    assert guarded["leaked_particles"] == 0
    assert all(r["wall_s_per_simulated_s"] > 0 for r in result.rows)
    speedup = result.rows[0]["wall_s_per_simulated_s"] / own["wall_s_per_simulated_s"]
    assert math.isclose(result.results["learned_speedup_over_serial"], speedup)
    assert result.results["discharge_rate_rel_error"] == own["discharge_rate_rel_error"]
    assert result.targets[0].name == "learned rollout speed / serial LIGGGHTS"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_on_a_gpu_the_suite_judges_the_rollout_against_liggghts_on_all_cores():
    result = run("pretrained:hopper", mpi_procs=(1, 2), threads=1, device="cuda")
    mpi = result.rows[1]["wall_s_per_simulated_s"]
    assert result.targets[-1].name.startswith("learned rollout on cuda / LIGGGHTS on all cores")
    assert math.isclose(
        result.results["learned_speedup_over_liggghts_all_cores"],
        mpi / result.rows[-1]["wall_s_per_simulated_s"],
    )
