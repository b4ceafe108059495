"""The MLP's in-place ReLU and row helpers give the plain layer-by-layer results and gradients."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.nn.mlp import MLP, add, relu, take_rows


def _outputs_and_grads(mlp: MLP, x: torch.Tensor, plain: bool):
    mlp.zero_grad()
    x = x.clone().requires_grad_()
    y = torch.nn.Sequential.forward(mlp, x) if plain else mlp(x)
    weights = torch.linspace(-1.0, 2.0, y.numel()).reshape(y.shape)
    (y.float() * weights).sum().backward()
    return [y.detach().float(), x.grad] + [p.grad.clone() for p in mlp.parameters()]


@pytest.mark.parametrize("autocast", [False, True], ids=["float32", "bf16-autocast"])
def test_mlp_equals_the_plain_sequential_with_its_gradients(autocast):
    torch.manual_seed(0)
    mlp = MLP(6, 16, 5, num_hidden_layers=2, layer_norm=True)
    x = torch.randn(40, 6)
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        ours = _outputs_and_grads(mlp, x, plain=False)
        plain = _outputs_and_grads(mlp, x, plain=True)
    for a, b in zip(ours, plain, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)  # the same kernels, the same numbers


def test_relu_and_add_work_in_place_for_float32_only():
    h = torch.tensor([-1.0, 2.0])
    assert relu(h) is h and h.tolist() == [0.0, 2.0]
    b = torch.tensor([-1.0, 2.0], dtype=torch.bfloat16)
    out = relu(b)
    assert out is not b and out.tolist() == [0.0, 2.0] and b.tolist() == [-1.0, 2.0]
    a = torch.tensor([1.0, 1.0])
    assert add(a, h) is a and a.tolist() == [1.0, 3.0]
    c = torch.ones(2, dtype=torch.bfloat16)
    assert add(c, b).tolist() == [0.0, 3.0] and c.tolist() == [1.0, 1.0]


def test_take_rows_is_the_tensor_itself_for_all_rows_and_a_view_otherwise():
    x = torch.arange(12.0).reshape(4, 3).requires_grad_()
    assert take_rows(x, None) is x
    assert take_rows(x, slice(1, 3)).tolist() == [[3.0, 4.0, 5.0], [6.0, 7.0, 8.0]]
    assert take_rows(x, slice(0, 2), dim=1).tolist() == [
        [0.0, 1.0],
        [3.0, 4.0],
        [6.0, 7.0],
        [9.0, 10.0],
    ]
