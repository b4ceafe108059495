"""The multilayer perceptron used by every encoder, processor and decoder."""

from __future__ import annotations

from torch import nn

from granular_pyg.errors import InputError

__all__ = ["MLP"]


def _check_int(name: str, value: object, minimum: int) -> int:
    """Return ``value`` as an int, or raise :class:`InputError` if it is not an int >= minimum."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise InputError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


class MLP(nn.Sequential):
    """``num_hidden_layers`` x (Linear -> ReLU), then Linear to ``out_dim`` (+ LayerNorm).

    GNS style: every encoder and processor MLP ends in a LayerNorm of its output; the decoder's
    does not (``layer_norm=False``), so it can reach any acceleration scale.

    Args:
        in_dim: input width.
        hidden_dim: width of each hidden layer.
        out_dim: output width.
        num_hidden_layers: number of Linear -> ReLU blocks before the output Linear (0 gives a
            single Linear layer).
        layer_norm: end with ``LayerNorm(out_dim)``.

    Shapes:
        input ``[*, in_dim]`` -> output ``[*, out_dim]`` (any leading dimensions, also zero rows).

    Raises:
        InputError: a width below 1 or a negative number of hidden layers.
    """

    def __init__(
        self,
        in_dim: int,
        hidden_dim: int,
        out_dim: int,
        num_hidden_layers: int = 2,
        layer_norm: bool = True,
    ) -> None:
        in_dim = _check_int("in_dim", in_dim, 1)
        hidden_dim = _check_int("hidden_dim", hidden_dim, 1)
        out_dim = _check_int("out_dim", out_dim, 1)
        num_hidden_layers = _check_int("num_hidden_layers", num_hidden_layers, 0)
        layers: list[nn.Module] = []
        width = in_dim
        for _ in range(num_hidden_layers):
            layers += [nn.Linear(width, hidden_dim), nn.ReLU()]
            width = hidden_dim
        layers.append(nn.Linear(width, out_dim))
        if layer_norm:
            layers.append(nn.LayerNorm(out_dim))
        super().__init__(*layers)
        self.in_dim = in_dim
        self.out_dim = out_dim
