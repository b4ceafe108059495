"""``data.mask_beyond_reach``: in a step that removes the lid or follows its removal, only
the particles the model's message passing can reach from it keep their target; every other
window is untouched."""

from __future__ import annotations

import math

import numpy as np
import torch
import trimesh

from granular_pyg.data.windows import WindowDataset
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.training.data_module import _Collate
from granular_pyg.training.objectives import masked_mse


def _model() -> LearnedSimulator:
    torch.manual_seed(0)
    sim = LearnedSimulator(Processor(latent=16, num_steps=2), radius=0.0075, latent=16, dt=0.0025)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    return sim.eval()


def test_only_particles_within_reach_of_the_removed_lid_keep_their_target():
    sim = _model()
    assert math.isclose(sim.reach, 2 * 0.0075)  # two message-passing steps of the cut-off
    data = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1)
    lid = data.trajs[0].scene.wall("lid")
    mesh = trimesh.Trimesh(lid.vertices_at(0.0), lid.faces, process=False)
    masked, plain = _Collate(sim, 0.0, 0, mask_beyond_reach=True), _Collate(sim, 0.0, 0)
    events = 0
    for i in range(len(data)):
        w = data[i]
        if w.time > 0.04:  # the lid goes at 0.02 s; later windows are like the ones before
            continue
        y, y_plain = masked([w]).y, plain([w]).y
        dt = float(sim.dt)
        if not w.time - dt - 1e-9 <= lid.removal_time <= w.time + dt + 1e-9:
            assert torch.equal(y, y_plain), w.time  # no event: every target kept
            continue
        events += 1
        _, distance, _ = trimesh.proximity.closest_point(mesh, w.pos_seq[:, -1].double().numpy())
        kept = torch.isfinite(y).all(dim=1).numpy()
        np.testing.assert_array_equal(kept, distance < sim.reach)
        assert 0 < kept.sum() < len(kept)
        torch.testing.assert_close(y[kept], y_plain[kept], rtol=0, atol=0)
        loss = masked_mse(torch.zeros_like(y), y)
        assert torch.isfinite(loss) and loss == (y_plain[kept] ** 2).mean()
    assert events == 3  # the steps ending at, starting from and one after the removal
