"""``data.rest_weight``: the one-step loss weighs the particles at rest in their history."""

from __future__ import annotations

import torch

from granular_pyg.data.windows import WindowDataset
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.sleep import REST_SPEED, at_rest
from granular_pyg.training.data_module import _Collate
from granular_pyg.training.objectives import OneStep, masked_mse


def test_weighted_mse_tiny_case():
    pred = torch.zeros(3, 3)
    target = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [float("nan"), 0.0, 0.0]])
    weight = torch.tensor([10.0, 1.0, 5.0])
    # rows 0 and 1 known: (10 * 1 + 1 * 4) / (2 rows * 3 components)
    torch.testing.assert_close(masked_mse(pred, target, weight), torch.tensor(14.0 / 6.0))
    assert masked_mse(pred, target, torch.ones(3)) == masked_mse(pred, target)


def test_at_rest_is_the_slowest_step_against_one_mm_per_second():
    dt = 0.04
    seq = torch.zeros(4, 6, 3)
    seq[1, 3:, 0] = 0.5 * REST_SPEED * dt  # one step at half the threshold: at rest
    seq[2, 5:, 2] = -2.0 * REST_SPEED * dt  # the last step at twice it: moving
    seq[3] = torch.linspace(0, 1, 6)[:, None] * 5 * REST_SPEED * dt  # 1 mm/s along a diagonal
    assert at_rest(seq, dt).tolist() == [True, True, False, False]
    # the same along any horizontal direction or upside down: only the speed counts
    turned = seq @ torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]).T
    assert at_rest(turned, dt).tolist() == at_rest(seq, dt).tolist()


def test_the_loss_weighs_the_particles_at_rest_in_their_history():
    torch.manual_seed(0)
    sim = LearnedSimulator(Processor(latent=16, num_steps=2), radius=0.0075, latent=16, dt=0.0025)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    data = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1)
    early = data[0]  # the settled bed before the lid goes: every particle at rest
    rest_counts = [int(at_rest(data[i].pos_seq, 0.0025).sum()) for i in range(len(data))]
    # the lid has gone: the bed starts to move from below, its top still at rest
    late = data[next(i for i, n in enumerate(rest_counts) if 0 < n < len(early.pos_seq))]
    weighted, plain = _Collate(sim, 0.0, 0, rest_weight=7.0), _Collate(sim, 0.0, 0)
    assert "weight" not in plain([early])
    for w in (early, late):
        batch = weighted([w])
        rest = at_rest(w.pos_seq, 0.0025)
        assert torch.equal(batch.weight, torch.where(rest, 7.0, 1.0))
        with torch.no_grad():
            pred = sim(batch)
        err = ((pred - batch.y) ** 2).sum(1)
        expected = (7.0 * err[rest].sum() + err[~rest].sum()) / (3 * len(err))
        torch.testing.assert_close(OneStep().loss(sim, batch, None), expected)
    assert at_rest(early.pos_seq, 0.0025).all()
    assert 0 < at_rest(late.pos_seq, 0.0025).sum() < len(late.pos_seq)
