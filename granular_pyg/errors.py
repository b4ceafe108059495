"""Exceptions and input checks shared by the whole package.

Every check raises :class:`InputError` with one message that names the offending input and says
how to fix it, so a user never has to read a traceback from deep inside torch.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


class InputError(ValueError):
    """Bad user input (wrong shape or dtype, NaN/Inf, degenerate or empty data)."""


def check_tensor(
    name: str,
    value: torch.Tensor,
    shape: Sequence[int | None],
    *,
    floating: bool = True,
    finite: bool = True,
) -> None:
    """Check a tensor's shape (``None`` matches any size), dtype kind and finiteness.

    Args:
        name: how the caller calls the argument, e.g. ``"points"``.
        value: the tensor to check.
        shape: expected shape, ``None`` for a free dimension, e.g. ``(None, 3)``.
        floating: require a floating dtype (float32 or float64).
        finite: require every entry to be finite (costs one reduction).

    Raises:
        InputError: naming ``name``, what was expected and what was found.
    """
    if not isinstance(value, torch.Tensor):
        raise InputError(f"{name}: expected a torch.Tensor, got {type(value).__name__}")
    if value.dim() != len(shape) or any(
        want is not None and got != want for got, want in zip(value.shape, shape, strict=True)
    ):
        want_str = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise InputError(f"{name}: expected shape {want_str}, got {list(value.shape)}")
    if floating and value.dtype not in (torch.float32, torch.float64):
        raise InputError(
            f"{name}: expected float32 or float64, got {value.dtype}; convert with .float()"
        )
    if finite and floating and value.numel() and not bool(torch.isfinite(value).all()):
        bad = (~torch.isfinite(value)).reshape(value.shape[0], -1).any(dim=1).nonzero()
        first = bad[:5, 0].tolist()
        raise InputError(
            f"{name}: {len(bad)} row(s) contain NaN or Inf (first rows: {first}); "
            "remove or repair them before calling"
        )
