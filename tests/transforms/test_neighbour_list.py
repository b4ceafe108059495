"""NeighbourList: the same edges as a fresh radius graph at every step, with fewer searches."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from granular_pyg.errors import InputError
from granular_pyg.transforms import NeighbourList, radius_graph


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10**6), dtype=st.sampled_from([torch.float32, torch.float64]))
def test_every_step_equals_a_fresh_radius_graph(seed, dtype):
    gen = torch.Generator().manual_seed(seed)
    pos = (torch.rand(300, 3, generator=gen) * 0.05).to(dtype)
    nl = NeighbourList(0.008, skin=0.002)
    for _ in range(30):
        pos = pos + (torch.rand(pos.shape, generator=gen, dtype=dtype) - 0.5) * 4e-4
        assert torch.equal(nl(pos), radius_graph(pos, 0.008))
    assert nl.calls == 30 and 1 <= nl.builds < 30


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10**6))
def test_only_the_fast_particles_are_searched_again(seed):
    """A bed that barely moves with a few particles falling fast through it (a discharging
    hopper): partial searches, and still the fresh graph at every step."""
    gen = torch.Generator().manual_seed(seed)
    pos = torch.rand(400, 3, generator=gen) * 0.05
    fast = torch.randperm(400, generator=gen)[:12]
    nl = NeighbourList(0.008, skin=0.002)
    for _ in range(25):
        pos = pos + (torch.rand(pos.shape, generator=gen) - 0.5) * 2e-4
        pos[fast, 2] -= 0.003  # 3 mm per step, beyond the skin
        assert torch.equal(nl(pos), radius_graph(pos, 0.008))
    assert nl.builds == 1 and nl.refreshes >= 20


def test_a_move_beyond_half_the_skin_triggers_a_search():
    pos = torch.tensor([[0.0, 0, 0], [0.009, 0, 0]] + [[0.1 * k, 0.1, 0] for k in range(8)])
    nl = NeighbourList(0.008, skin=0.002)
    assert nl(pos).shape[1] == 0 and nl.builds == 1
    pos[1, 0] = 0.0085  # moved 0.5 mm < skin / 2: filtered from the candidates
    assert nl(pos).shape[1] == 0 and nl.builds == 1
    pos[1, 0] = 0.0075  # moved 1.5 mm > skin / 2: its pairs are searched again, an edge both ways
    assert nl(pos).tolist() == [[1, 0], [0, 1]] and nl.refreshes == 1 and nl.builds == 1


def test_when_most_particles_move_the_list_steps_aside_then_comes_back():
    """Reuse cannot pay while most particles leave their skin every step: plain graphs (no
    skin) until they slow down, then one skinned search and reuse again."""
    gen = torch.Generator().manual_seed(4)
    pos = torch.rand(300, 3, generator=gen) * 0.05
    nl = NeighbourList(0.008, skin=0.002)
    for step in range(30):
        jump = 2e-3 if 5 <= step < 15 else 1e-4  # 2 mm per step: beyond the skin
        pos = pos + (torch.rand(pos.shape, generator=gen) - 0.5) * jump
        assert torch.equal(nl(pos), radius_graph(pos, 0.008))
    assert nl.plain == 10  # steps 5-14
    assert nl.builds == 2  # the first call, then back at step 15


def test_particles_that_leave_are_dropped_without_a_search():
    gen = torch.Generator().manual_seed(0)
    pos = torch.rand(200, 3, generator=gen) * 0.04
    nl = NeighbourList(0.008, skin=0.002)
    nl(pos, torch.arange(200))
    keep = torch.ones(200, dtype=torch.bool)
    keep[[3, 50, 199]] = False
    ids = keep.nonzero().squeeze(1)
    assert torch.equal(nl(pos[keep], ids), radius_graph(pos[keep], 0.008))
    assert nl.builds == 1
    # A particle that was not there before forces a search.
    assert torch.equal(nl(pos, torch.arange(200)), radius_graph(pos, 0.008))
    assert nl.builds == 2


def test_bad_arguments_are_input_errors():
    with pytest.raises(InputError, match="skin"):
        NeighbourList(0.01, skin=0.0)
    with pytest.raises(InputError, match="ids"):
        NeighbourList(0.01, 0.001)(torch.zeros(3, 3), torch.arange(2))
    with pytest.raises(InputError, match="pos"):
        NeighbourList(0.01, 0.001)(torch.full((2, 3), float("nan")))


def test_a_rollout_with_reuse_equals_one_without():
    from hydra.utils import instantiate

    from granular_pyg.config import compose
    from granular_pyg.io import read_trajectory
    from granular_pyg.samples import sample_files
    from granular_pyg.scenes import WallSet

    torch.manual_seed(0)
    sim = instantiate(compose("train", ["model.latent=16"]).model).eval()
    traj = read_trajectory(sample_files("hopper", "test")[0])
    seq = torch.from_numpy(traj.positions[20:26]).permute(1, 0, 2).contiguous()
    walls, t0 = WallSet(traj.scene), float(traj.times[25])
    fresh = sim.rollout(seq, walls, t0, 12, traj.scene.outflow_z)
    reused = sim.rollout(seq, walls, t0, 12, traj.scene.outflow_z, skin=0.001)
    assert torch.equal(torch.isnan(fresh), torch.isnan(reused))
    np.testing.assert_array_equal(fresh.numpy(), reused.numpy())


def test_unsorted_radius_graph_has_the_same_edge_set():
    pos = torch.rand(500, 3, generator=torch.Generator().manual_seed(2)) * 0.05
    fast = radius_graph(pos, 0.008, sort=False)
    ordered = radius_graph(pos, 0.008)
    assert fast.shape == ordered.shape
    key = lambda e: torch.sort(e[1] * 500 + e[0]).values  # noqa: E731
    assert torch.equal(key(fast), key(ordered))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_pairs_kept_untested_are_within_the_radius_at_the_extreme_moves(dtype):
    """Pairs closer than radius - skin at the references are kept without a distance test:
    moved apart by (almost) half the skin each, they must still be edges, as a fresh graph
    says; pairs just outside that bound are measured."""
    radius, skin = 0.008, 0.002
    gaps = radius - skin + torch.tensor([-1e-9, 0.0, 1e-9, 5e-4], dtype=torch.float64)
    pos = torch.zeros(8, 3, dtype=torch.float64)
    pos[1::2, 0] = gaps
    pos[:, 1] = torch.arange(4, dtype=torch.float64).repeat_interleave(2) * 0.1  # pairs apart
    nl = NeighbourList(radius, skin)
    assert torch.equal(nl(pos.to(dtype)), radius_graph(pos.to(dtype), radius))
    step = 0.5 * skin - 2e-6 * (radius + skin)  # just inside the list's move limit
    pos[0::2, 0] -= step
    pos[1::2, 0] += step
    moved = pos.to(dtype)
    assert torch.equal(nl(moved), radius_graph(moved, radius))
    assert nl.builds == 1 and nl.refreshes == 0 and nl.plain == 0
    assert nl(moved).shape[1] == 6  # the three pairs still closer than the radius, both ways
