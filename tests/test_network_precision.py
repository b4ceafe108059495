"""bfloat16 network precision at inference: where its precision holds (one step, against the
float32 network) and that it leaves the rest of the rollout in float32."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from granular_pyg.errors import InputError
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files


@pytest.fixture(scope="module")
def hopper():
    sim, _ = load_simulator("pretrained:hopper")
    return sim, read_trajectory(sample_files("hopper", "test")[0])


def test_one_bf16_step_lands_within_a_tenth_of_a_particle_radius_of_float32(hopper):
    sim, truth = hopper
    with torch.inference_mode():
        full = rollout_trajectory(sim, truth, 1, progress=False)
        half = rollout_trajectory(sim, truth, 1, progress=False, precision="bf16")
    assert half.positions.dtype == full.positions.dtype == np.float32
    gap = np.nanmax(np.abs(half.positions[-1] - full.positions[-1]))
    # measured 3.3e-5 m for the shipped hopper model: 2% of the smallest radius
    assert 0 < gap < 0.1 * truth.radii.min()
    assert half.metadata["precision"] == "bf16" and full.metadata["precision"] == "32"
    assert sim.network_dtype is None  # the rollout restores the model's precision


def test_bf16_accelerations_are_within_two_percent_of_float32(hopper):
    sim, truth = hopper
    seq = torch.from_numpy(truth.positions[:6]).permute(1, 0, 2).contiguous()
    from granular_pyg.scenes import WallSet
    from granular_pyg.simulator import ParticleProps

    walls, props = WallSet(truth.scene), ParticleProps.of(truth)
    with torch.inference_mode():
        graph = sim.build_graph(seq, walls, float(truth.times[5]), props=props)
        full = sim(graph)
        sim.set_network_precision("bf16")
        try:
            half = sim(graph)
        finally:
            sim.set_network_precision("32")
    assert half.dtype == torch.float32
    assert float((half - full).norm() / full.norm()) < 0.02


def test_an_unknown_precision_is_refused_by_name(hopper):
    sim, truth = hopper
    with pytest.raises(InputError, match=r"precision: expected one of \['32', 'bf16'\], got 'fp8'"):
        rollout_trajectory(sim, truth, 1, progress=False, precision="fp8")
    assert sim.network_dtype is None
