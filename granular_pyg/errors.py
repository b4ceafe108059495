"""Exceptions and input checks shared by the whole package.

Every check raises :class:`InputError` with one message that names the offending input and says
how to fix it, so a user never has to read a traceback from deep inside torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch


class InputError(ValueError):
    """Bad user input (wrong shape or dtype, NaN/Inf, degenerate or empty data)."""


def whole_number(name: str, value, minimum: int = 0) -> int:
    """``value`` as an int ``>= minimum``: an int, or a float with no fractional part (``1e3``).

    Raises:
        InputError: naming ``name`` and the value (``2.7``, ``"abc"``, ``-1``, ``True``).
    """
    ok = isinstance(value, int) and not isinstance(value, bool)
    if isinstance(value, float) and value.is_integer():
        value, ok = int(value), True
    if not ok or value < minimum:
        raise InputError(f"{name}: expected a whole number >= {minimum}, got {value!r}")
    return value


def positive_number(name: str, value) -> float:
    """``value`` as a finite float ``> 0`` (an int or float; not a bool or a string).

    Raises:
        InputError: naming ``name`` and the value (``"abc"``, ``0``, ``-1e-3``, ``inf``).
    """
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok or not math.isfinite(value) or value <= 0:
        raise InputError(f"{name}: expected a finite number > 0, got {value!r}")
    return float(value)


def flag(name: str, value) -> bool:
    """``value`` as a bool: only ``True`` or ``False`` (``"no"``, ``"flase"``, ``1`` and None
    are refused: a non-empty string is true to Python, so ``overwrite=no`` would replace a file).

    Raises:
        InputError: naming ``name`` and the value.
    """
    if not isinstance(value, bool):
        raise InputError(
            f"{name}: expected true or false, got {value!r}; write {name}=true or {name}=false"
        )
    return value


def finite_number(name: str, value, minimum: float | None = None) -> float:
    """``value`` as a finite float (an int or float; not a bool or a string), ``>= minimum``
    when one is given.

    Raises:
        InputError: naming ``name`` and the value (``nan``, ``-1e-4`` below a minimum of 0).
    """
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok or not math.isfinite(value) or (minimum is not None and value < minimum):
        bound = f" >= {minimum:g}" if minimum is not None else ""
        raise InputError(f"{name}: expected a finite number{bound}, got {value!r}")
    return float(value)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, with what was kept: its message says where the work done so far went (or that
    nothing was kept); :func:`granular_pyg.cli.reports_errors` prints it as one line."""


class NonFiniteError(ArithmeticError):
    """A learned step predicted NaN or Inf for a particle that had not left.

    Attributes:
        step: index of the failing learned step in the rollout (0 = the first prediction).
        particle_ids: indices (rows of the rollout's particle set) of the failing particles.
        positions_so_far: ``[step, N, 3]`` the rollout's predictions before the failing step
            (set by ``LearnedSimulator.rollout``), so that nothing computed is lost.
        partial: the same as a Trajectory with its initial states (set by
            ``inference.rollout_trajectory``; ``python -m granular_pyg.rollout`` writes it).
    """

    def __init__(self, message: str, particle_ids: list[int], step: int | None = None) -> None:
        super().__init__(message)
        self.particle_ids, self.step = particle_ids, step
        self.positions_so_far: torch.Tensor | None = None
        self.partial = None


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


#: Largest float spacing at the scene's coordinates, as a fraction of the cut-off radius.
COORDINATE_ULP_FRACTION = 1e-4


def check_coordinates_fit(name: str, pos: torch.Tensor, radius: float) -> None:
    """Refuse coordinates too large for ``pos.dtype`` to resolve the motion of one step.

    Velocities are differences of positions a step apart, so the float spacing (ulp) at the
    scene's largest coordinate must stay below ``COORDINATE_ULP_FRACTION`` of the cut-off
    ``radius`` (m): in float32 with a 7.5 mm cut-off, coordinates up to about 6 m.

    Raises:
        InputError: naming the largest coordinate, the limit and the fixes.
    """
    if not pos.numel():
        return
    largest = float(pos.detach().abs().max())
    ulp = torch.finfo(pos.dtype).eps * largest
    if ulp > COORDINATE_ULP_FRACTION * radius:
        limit = COORDINATE_ULP_FRACTION * radius / torch.finfo(pos.dtype).eps
        raise InputError(
            f"{name}: coordinates up to {largest:.3g} m, beyond the {limit:.3g} m that "
            f"{str(pos.dtype).removeprefix('torch.')} resolves for a {radius:g} m cut-off; "
            "move the scene's origin into it, or roll out with dtype=float64"
        )
