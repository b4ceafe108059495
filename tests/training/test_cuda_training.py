"""Training on a GPU (skipped without CUDA): the geometry stays on the CPU, the features and the
network run on the model's device, and the result is the CPU's."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.config import compose
from granular_pyg.geometry import horizontal_frame
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import ParticleProps
from granular_pyg.train import train
from tests.test_symmetries import _sim, _window

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"),
]


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
def test_cuda_prediction_and_its_gradient_equal_the_cpus(processor):
    """A window on the CPU given to a model on CUDA (as training's loader does) and a window on
    CUDA (as the unrolled objective does) give the CPU model's acceleration, in a turned frame,
    and the same gradient with respect to the positions."""
    traj, seq, t, present = _window("drum", 40)
    props = ParticleProps(torch.from_numpy(traj.radii).double()[present])
    walls, q = WallSet(traj.scene), horizontal_frame(37.0, mirror=True)
    results = []
    for device, where in (("cpu", "cpu"), ("cuda", "cpu"), ("cuda", "cuda")):
        sim = _sim(processor, "both").to(device)
        pos = seq.clone().to(where).requires_grad_(True)
        acc = sim.predict_acceleration(pos, walls, t, props=props, frame=q)
        acc.square().sum().backward()
        assert acc.device.type == device
        results.append((acc.detach().cpu(), pos.grad.cpu()))
    for acc, grad in results[1:]:
        assert torch.allclose(acc, results[0][0], atol=1e-9, rtol=1e-9)
        assert torch.allclose(grad, results[0][1], atol=1e-9, rtol=1e-6)


def test_a_short_run_trains_on_the_gpu(tmp_path):
    """Three steps of the equivariant model with augmentation and the unrolled objective on
    CUDA: a finite loss and a checkpoint."""
    cfg = compose(
        "train",
        [
            "model/processor=equivariant",
            "model.latent=16",
            "objective=unrolled",
            "data.batch_size=1",
            "trainer.accelerator=gpu",
            "trainer.max_steps=3",
            "trainer.enable_progress_bar=false",
            "rollout_validation.every_n_epochs=null",
        ],
    )
    metrics = train(cfg, out_dir=tmp_path)
    assert torch.isfinite(torch.tensor(metrics["train/loss"]))
    assert (tmp_path / "checkpoints" / "last.ckpt").is_file()
