"""The multilayer perceptron used by every encoder, processor and decoder."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

from granular_pyg.errors import InputError

__all__ = ["MLP", "ROW_CHUNK", "add", "fill_by_blocks", "relu", "row_chunks", "take_rows"]

#: Rows per block of the blocked inference path: 4,096 rows of 128 float32 are 2 MiB, so a
#: block's hidden activations stay in a core's L2 cache instead of streaming through memory.
ROW_CHUNK = 4096


def row_chunks(rows: int, chunk: int | None = None):
    """Slices of ``rows`` in blocks of ``chunk`` (default :data:`ROW_CHUNK`) rows."""
    chunk = chunk or ROW_CHUNK
    return (slice(start, min(start + chunk, rows)) for start in range(0, rows, chunk))


def blocked_inference(rows: int) -> bool:
    """Whether a layer over ``rows`` rows takes the blocked path: no autograd graph is being
    recorded (inference, rollouts) and there is more than one block."""
    return rows > ROW_CHUNK and not torch.is_grad_enabled()


def relu(h: Tensor) -> Tensor:
    """ReLU of ``h``: in place for float32, out of place otherwise. In place spares a buffer,
    but PyTorch's in-place bfloat16 kernels on CPU run 2-3x slower than its out-of-place ones
    (``docs/results.md``, training throughput). In place is safe here, also under autograd:
    ``h`` is always a Linear layer's output, whose backward does not need it."""
    return h.relu_() if h.dtype == torch.float32 else torch.relu(h)


def add(a: Tensor, b: Tensor) -> Tensor:
    """``a + b``, into ``a`` for float32 (see :func:`relu`); ``a`` must be a fresh result."""
    return a.add_(b) if a.dtype == torch.float32 else a + b


def take_rows(x: Tensor, rows: slice | None, dim: int = 0) -> Tensor:
    """``x``'s rows ``rows`` along ``dim``, or ``x`` itself for ``None`` (all rows). Slicing all
    rows would record a slice in the autograd graph whose backward writes a zero-filled copy of
    the whole gradient; ``None`` records nothing."""
    return x if rows is None else x.narrow(dim, rows.start, rows.stop - rows.start)


def fill_by_blocks(out: Tensor, block: Callable[[slice], Tensor]) -> Tensor:
    """Write ``block(rows)`` (``[rows, *]``) into ``out[rows]`` for each block of rows of
    ``out [R, *]`` (:func:`row_chunks`); returns ``out``, now filled."""
    for rows in row_chunks(out.shape[0]):
        out[rows] = block(rows)
    return out


def _storage_dtype(x: Tensor) -> torch.dtype:
    """The autocast dtype of ``x``'s device when autocast is on there, else ``x.dtype``."""
    device = x.device.type
    return torch.get_autocast_dtype(device) if torch.is_autocast_enabled(device) else x.dtype


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

    def forward(self, x: Tensor, store_in_autocast_dtype: bool = False) -> Tensor:
        """``[*, in_dim] -> [*, out_dim]``. Without autograd and over more than
        :data:`ROW_CHUNK` rows, the rows run in cache-sized blocks, so the
        hidden activations never exist for all rows at once: same result, less memory traffic
        and a peak of one block's activations. On that path, ``store_in_autocast_dtype`` under
        autocast stores the output in the autocast dtype (bfloat16: half the memory of the
        largest buffer, the edge latents)."""
        if x.dim() != 2 or not blocked_inference(x.shape[0]):
            return self.run_block(x)
        dtype = _storage_dtype(x) if store_in_autocast_dtype else x.dtype
        out = x.new_empty(x.shape[0], self.out_dim, dtype=dtype)
        return fill_by_blocks(out, lambda rows: self.run_block(x[rows]))

    def run_block(self, h: Tensor, start: int = 0) -> Tensor:
        """The layers from index ``start`` on, over one block of rows (ReLU by :func:`relu`)."""
        for module in list(self)[start:]:
            h = relu(h) if isinstance(module, nn.ReLU) else module(h)
        return h
