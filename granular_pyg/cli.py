"""The one wrapper around every ``python -m granular_pyg.<command>`` entry point.

``@command("train")`` turns ``main(cfg)`` into a Hydra app over ``conf/train.yaml`` (the folder
that :data:`granular_pyg.config.CONF_DIR` names, so a wheel runs without a checkout) and gives
every command the same error style: an expected failure (bad input, a missing or unwritable
file, a full disk, a model that predicted NaN) prints one ``error:`` message that names the
thing and the fix, and exits with status 2. A traceback is printed only with
``GRANULAR_PYG_DEBUG=1`` or ``HYDRA_FULL_ERROR=1``.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable

import hydra

from granular_pyg.config import CONF_DIR
from granular_pyg.errors import InputError, NonFiniteError

__all__ = ["EXIT_INPUT_ERROR", "command", "debugging", "reports_errors"]

#: Exit status of a command stopped by bad input or an expected failure.
EXIT_INPUT_ERROR = 2


def debugging() -> bool:
    """Whether the user asked for full tracebacks."""
    flags = ("GRANULAR_PYG_DEBUG", "HYDRA_FULL_ERROR")
    return any(os.environ.get(k, "") not in ("", "0") for k in flags)


def _expected(exc: BaseException) -> BaseException | None:
    """The expected failure behind ``exc`` (Hydra's ``instantiate`` wraps what a constructor
    raised), or None for a bug."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (InputError, NonFiniteError, OSError)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _message(exc: BaseException) -> str:
    if isinstance(exc, (InputError, NonFiniteError)):
        return str(exc)
    # OSError: a missing file, no permission, a full disk (strerror names the cause)
    where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
    what = exc.strerror or str(exc)
    fix = " (free some space or choose another out=)" if exc.errno == 28 else ""
    return f"{what}{where}{fix}"


def reports_errors(func: Callable) -> Callable:
    """Wrap a command's ``main``: an expected failure becomes one ``error:`` line on standard
    error and exit status 2 (a traceback with ``GRANULAR_PYG_DEBUG=1``)."""

    @functools.wraps(func)
    def run(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except Exception as exc:
            expected = _expected(exc)
            if expected is None or debugging():
                raise
            print(f"error: {_message(expected)}", file=sys.stderr)
            sys.exit(EXIT_INPUT_ERROR)

    return run


def command(config_name: str) -> Callable[[Callable], Callable]:
    """Decorate ``main(cfg)`` as the Hydra entry point over ``conf/<config_name>.yaml``, with
    :func:`reports_errors`."""

    def decorate(func: Callable) -> Callable:
        app = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name=config_name)
        return app(reports_errors(func))

    return decorate
