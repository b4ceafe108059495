"""AddRandomWalkNoise and AddWallNodes on real scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch_geometric.data import Data

from granular_pyg.errors import InputError
from granular_pyg.scenes import WallSet, make_hopper
from granular_pyg.transforms.add_random_walk_noise import AddRandomWalkNoise
from granular_pyg.transforms.add_wall_nodes import AddWallNodes


def _sequence(num=20000, steps=5, seed=0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    start = torch.rand(num, 1, 3, generator=g, dtype=torch.float64) * 0.01
    vel = torch.tensor([0.0, 0.0, -1e-4], dtype=torch.float64)
    return start + vel * torch.arange(steps + 1, dtype=torch.float64)[None, :, None]


def test_random_walk_noise_has_the_requested_last_velocity_std():
    seq = _sequence()
    sigma = 3e-5
    data = AddRandomWalkNoise(sigma, generator=torch.Generator().manual_seed(1))(
        Data(pos_seq=seq.clone(), target_pos=seq[:, -1] + 1e-4)
    )
    noise = data.pos_seq - seq
    assert torch.equal(noise[:, 0], torch.zeros_like(noise[:, 0]))  # oldest frame untouched
    last_velocity_noise = noise[:, -1] - noise[:, -2]
    assert float(last_velocity_noise.std()) == pytest.approx(sigma, rel=0.03)
    first_velocity_noise = noise[:, 1] - noise[:, 0]
    assert float(first_velocity_noise.std()) == pytest.approx(sigma / math.sqrt(5), rel=0.03)
    # The target moves with the last position's noise (GNS), and pos is the noisy current one.
    torch.testing.assert_close(data.target_pos, seq[:, -1] + 1e-4 + noise[:, -1])
    assert torch.equal(data.pos, data.pos_seq[:, -1])


def test_correcting_positions_keeps_the_clean_target():
    """With ``correct_positions`` the inputs get the same noise, but the target stays clean, so
    the target acceleration undoes the position noise: a pair pressed together by the noise is
    asked to move apart."""
    seq = _sequence(1000)
    target = seq[:, -1] + 1e-4
    gns, clean = (
        AddRandomWalkNoise(3e-5, generator=torch.Generator().manual_seed(1), correct_positions=c)
        for c in (False, True)
    )
    a = gns(Data(pos_seq=seq.clone(), target_pos=target.clone()))
    b = clean(Data(pos_seq=seq.clone(), target_pos=target.clone()))
    assert torch.equal(a.pos_seq, b.pos_seq)
    assert torch.equal(b.target_pos, target)
    torch.testing.assert_close(a.target_pos - b.target_pos, a.pos_seq[:, -1] - seq[:, -1])


def test_a_held_offset_moves_every_frame_alike_and_never_the_target():
    """``offset_std``: one displacement per particle over the whole history, so the velocities
    stay clean and the target stays the clean next position (push a displaced particle back);
    without it the walk's draws are bit for bit those of before."""
    seq = _sequence(4000)
    target = seq[:, -1] + 1e-4
    data = AddRandomWalkNoise(0.0, generator=torch.Generator().manual_seed(3), offset_std=2e-4)(
        Data(pos_seq=seq.clone(), target_pos=target.clone())
    )
    shift = data.pos_seq - seq
    torch.testing.assert_close(shift, shift[:, :1].expand_as(shift), rtol=0, atol=1e-17)
    assert float(shift[:, 0].std()) == pytest.approx(2e-4, rel=0.03)
    assert torch.equal(data.target_pos, target)  # velocity target or not, the offset is undone
    both = AddRandomWalkNoise(3e-5, generator=torch.Generator().manual_seed(1), offset_std=2e-4)
    walk = AddRandomWalkNoise(3e-5, generator=torch.Generator().manual_seed(1))
    with_offset = both(Data(pos_seq=seq.clone(), target_pos=target.clone()))
    alone = walk(Data(pos_seq=seq.clone(), target_pos=target.clone()))
    offset = (with_offset.pos_seq - alone.pos_seq)[:, :1]
    torch.testing.assert_close(with_offset.pos_seq, alone.pos_seq + offset, rtol=0, atol=1e-17)
    torch.testing.assert_close(with_offset.target_pos, alone.target_pos, rtol=0, atol=0)
    with pytest.raises(InputError, match="offset_std"):
        AddRandomWalkNoise(1e-5, offset_std=-1.0)


def test_a_shared_drift_moves_every_particle_alike_and_never_the_last_frame():
    """``drift_std``: one random walk for the whole window: every particle's velocities change
    alike, the last velocity's change has std ``drift_std`` and the first's ``drift_std /
    sqrt(H)``; the last position and the target stay clean (stop the drift); the per-particle
    walk's and the offset's draws are bit for bit those of before."""
    seq = _sequence(50)
    target = seq[:, -1] + 1e-4
    changes = []
    for seed in range(1000):
        noise = AddRandomWalkNoise(
            0.0, generator=torch.Generator().manual_seed(seed), drift_std=2e-4
        )
        data = noise(Data(pos_seq=seq.clone(), target_pos=target.clone()))
        change = torch.diff(data.pos_seq, dim=1) - torch.diff(seq, dim=1)  # [N, H, 3]
        torch.testing.assert_close(change, change[:1].expand_as(change), rtol=0, atol=1e-15)
        assert torch.equal(data.pos_seq[:, -1], seq[:, -1])
        assert torch.equal(data.target_pos, target)
        changes.append(change[0])
    changes = torch.stack(changes)  # [draws, H, 3]
    assert float(changes[:, -1].std()) == pytest.approx(2e-4, rel=0.05)
    assert float(changes[:, 0].std()) == pytest.approx(2e-4 / math.sqrt(5), rel=0.05)
    kwargs = {"correct_positions": True, "offset_std": 2e-4}
    drifted = AddRandomWalkNoise(
        3e-5, generator=torch.Generator().manual_seed(1), drift_std=2e-4, **kwargs
    )
    alone = AddRandomWalkNoise(3e-5, generator=torch.Generator().manual_seed(1), **kwargs)
    a = drifted(Data(pos_seq=seq.clone(), target_pos=target.clone()))
    b = alone(Data(pos_seq=seq.clone(), target_pos=target.clone()))
    torch.testing.assert_close(a.pos_seq[:, -1], b.pos_seq[:, -1], rtol=0, atol=0)
    torch.testing.assert_close(a.target_pos, b.target_pos, rtol=0, atol=0)
    with pytest.raises(InputError, match="drift_std"):
        AddRandomWalkNoise(0.0, drift_std=float("nan"))


def test_noise_target_must_be_velocity_or_position():
    from granular_pyg.training import TrajectoryDataModule

    with pytest.raises(InputError, match="noise_target"):
        TrajectoryDataModule(sample="hopper", noise_target="both")


def test_zero_noise_changes_nothing():
    seq = _sequence(100)
    data = AddRandomWalkNoise(0.0)(Data(pos_seq=seq.clone()))
    assert torch.equal(data.pos_seq, seq)


def test_noise_never_pushes_a_particle_through_a_wall_when_resampling():
    scene = make_hopper()
    walls = WallSet(scene)
    # Particles 0.1 mm above the lid (z = 0): noise of 0.2 mm would often cross it.
    num = 2000
    xy = torch.rand(num, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64) - 0.5
    pos = torch.cat([xy * torch.tensor([0.015, 0.025]), torch.full((num, 1), 1e-4)], 1)
    seq = pos[:, None, :].repeat(1, 6, 1)

    def crossed(resample: bool, std: float = 2e-4, offset_std: float = 0.0) -> int:
        noise = AddRandomWalkNoise(
            std,
            resample_at_walls=resample,
            generator=torch.Generator().manual_seed(2),
            offset_std=offset_std,
        )
        out = noise(Data(pos_seq=seq.clone(), walls=walls, time=0.0))
        return int((out.pos[:, 2] < 0).sum())

    assert crossed(False) > 100
    assert crossed(True) == 0
    assert crossed(False, 0.0, 2e-4) > 100 and crossed(True, 0.0, 2e-4) == 0  # a held offset


def test_wall_nodes_none_when_no_triangle_is_near():
    walls = WallSet(make_hopper())
    data = AddWallNodes(0.005)(Data(pos=torch.tensor([[0.0, 0.0, 0.05]]), walls=walls, time=0.0))
    assert data.num_real == 1 and data.pos.shape == (1, 3)
    assert data.edge_index.shape == (2, 0) and not data.is_wall.any()


def test_wall_node_features_per_variant_and_the_one_over_k_weight():
    walls = WallSet(make_hopper())
    # A particle in the outlet's corner: near the lid, an incline and a side wall.
    corner = torch.tensor([[0.0095, 0.0145, 0.0008]])
    out = {}
    for variant in ("none", "single", "both"):
        data = AddWallNodes(0.003, variant, wall_weight=True)(
            Data(pos=corner, walls=walls, time=0.0)
        )
        out[variant] = data
    k = int(out["both"].is_wall.sum())
    assert k >= 3
    assert torch.equal(out["both"].node_weight[1:], torch.full((k,), 1.0 / k))
    assert (out["none"].normal_feat == 0).all()
    single = out["single"].normal_feat[1:]
    assert torch.allclose(single[:, :3].norm(dim=1), torch.full((k,), 1.0))
    assert (single[:, 3:] == 0).all()
    both = out["both"].normal_feat[1:]
    torch.testing.assert_close(both[:, 3:], -both[:, :3])
    np.testing.assert_array_equal(out["both"].edge_index[1].numpy(), np.zeros(k, dtype=int))


def test_removed_lid_gives_no_wall_nodes_after_t_open():
    scene = make_hopper(t_open=0.05)
    walls = WallSet(scene)
    below_lid = Data(pos=torch.tensor([[0.0, 0.0, 0.001]]), walls=walls, time=0.0)
    assert AddWallNodes(0.003)(below_lid).is_wall.sum() >= 1  # one per lid triangle near
    later = Data(pos=torch.tensor([[0.0, 0.0, 0.001]]), walls=walls, time=0.06)
    assert AddWallNodes(0.003)(later).is_wall.sum() == 0


def test_bad_settings_are_named():
    with pytest.raises(InputError, match="normals"):
        AddWallNodes(0.01, normals="double")
    with pytest.raises(InputError, match="std"):
        AddRandomWalkNoise(-1.0)
