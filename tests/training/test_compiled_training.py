"""``compile=true``: the torch.compile'd training step gives the eager step's loss and gradients
(float32, to round-off of the fused kernels), while validation and rollouts stay eager and
checkpoints keep the model's own parameter names."""

from __future__ import annotations

import torch

from tests.training.one_batch import loss_and_grads, model_objective_batch


def test_a_compiled_training_step_equals_the_eager_one():
    torch.manual_seed(0)
    sim, objective, batch = model_objective_batch(["model.latent=16", "data.batch_size=2"])
    eager_loss, eager = loss_and_grads(sim, objective, batch)
    keys = list(sim.state_dict())
    sim.compile_for_training()
    compiled_loss, compiled = loss_and_grads(sim, objective, batch)
    assert abs(compiled_loss - eager_loss) <= 1e-5 * abs(eager_loss)
    assert float((compiled - eager).abs().max()) <= 1e-4 * float(eager.abs().max())
    assert list(sim.state_dict()) == keys  # no "_orig_mod." names in checkpoints


def test_without_autograd_the_network_runs_eagerly():
    sim, _, batch = model_objective_batch(["model.latent=16"])
    sim.compile_for_training()

    def refuse(*args):
        raise AssertionError("the compiled network ran without autograd")

    sim._compiled_network = refuse
    with torch.no_grad():  # validation and rollouts
        assert torch.isfinite(sim(batch)).all()
