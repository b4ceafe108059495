"""The one wrapper around every ``python -m granular_pyg.<command>`` entry point.

``@command("train")`` turns ``main(cfg)`` into a Hydra app over ``conf/train.yaml`` (the folder
that :data:`granular_pyg.config.CONF_DIR` names, so a wheel runs without a checkout) and gives
every command the same error style: an expected failure (bad input, a missing or unwritable
file, a full disk, a model that predicted NaN) prints one ``error:`` message that names the
thing and the fix, and exits with status 2. A traceback is printed only with
``GRANULAR_PYG_DEBUG=1`` or ``HYDRA_FULL_ERROR=1``. A command line Hydra cannot compose (an
unknown key or option, a malformed override) is reported the same way, before any work starts.
A command run from the command line keeps freed memory in its heap
(:func:`granular_pyg.heap.keep_freed_memory`: no page faults for each step's large tensors).
"""

from __future__ import annotations

import functools
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import hydra
from hydra.errors import HydraException, InstantiationException
from omegaconf import OmegaConf
from omegaconf.errors import (
    InterpolationResolutionError,
    MissingMandatoryValue,
    OmegaConfBaseException,
)

from granular_pyg.config import CONF_DIR, flatten
from granular_pyg.errors import InputError, NonFiniteError, whole_number
from granular_pyg.heap import keep_freed_memory

__all__ = [
    "EXIT_INPUT_ERROR",
    "EXIT_INTERRUPTED",
    "check_booleans",
    "command",
    "debugging",
    "reports_errors",
    "task_overrides",
]

#: Exit status of a command stopped by bad input or an expected failure.
EXIT_INPUT_ERROR = 2
#: Exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130
#: Options whose default is true/false but which take other values too (Lightning's
#: ``save_last`` takes ``link``, ``fast_dev_run`` a number of batches, ``deterministic`` ``warn``;
#: Lightning checks them).
NOT_ONLY_BOOLEAN = frozenset(
    {"checkpoint.save_last", "trainer.fast_dev_run", "trainer.deterministic"}
)
#: Keys a user cannot set, with what sets them (an old command line's ``model.dt=...``).
SET_FOR_YOU = {
    "model.dt": "the learned step is data.frames_per_step x the training data's frame spacing, "
    "resolved before the model is built (and read from a checkpoint's model card); set "
    "data.frames_per_step instead",
}
#: Free space (bytes) a run folder's disk needs before a command starts (logs, checkpoints).
RUN_FOLDER_MIN_FREE = 50 * 2**20


def debugging() -> bool:
    """Whether the user asked for full tracebacks."""
    flags = ("GRANULAR_PYG_DEBUG", "HYDRA_FULL_ERROR")
    return any(os.environ.get(k, "") not in ("", "0") for k in flags)


def _config_value_error(exc: BaseException) -> InputError | None:
    """A ValueError or TypeError a constructor raised on a config value (wrapped by Hydra's
    ``instantiate``), as an InputError naming the config section; None otherwise."""
    cause = exc.__cause__
    if not isinstance(exc, InstantiationException) or not isinstance(cause, ValueError | TypeError):
        return None
    if isinstance(cause, InputError):  # names its own key
        return None
    section = next(
        (
            line[len("full_key:") :].strip()
            for line in str(exc).splitlines()
            if line.startswith("full_key:")
        ),
        "the config",
    )
    return InputError(
        f"{section}: {cause} (check the {section}.* values; GRANULAR_PYG_DEBUG=1 for the traceback)"
    )


def _expected(exc: BaseException) -> BaseException | None:
    """The expected failure behind ``exc`` (Hydra's ``instantiate`` wraps what a constructor
    raised; a ValueError or TypeError of a constructor is a bad config value), or None for a
    bug."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (InputError, NonFiniteError, OSError)):
            return exc
        if (wrapped := _config_value_error(exc)) is not None:
            return wrapped
        if (wrapped := _lightning_config_error(exc)) is not None:
            return wrapped
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _lightning_config_error(exc: BaseException) -> InputError | None:
    """Lightning's MisconfigurationException (a bad ``trainer.*`` value) as one line."""
    if type(exc).__name__ != "MisconfigurationException":
        return None
    first = " ".join(str(exc).split())
    return InputError(f"trainer: {first} (check the trainer.* values)")


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
        except KeyboardInterrupt as exc:
            if debugging():
                raise
            said = str(exc) or "nothing of this run was kept beyond the files it had finished"
            print(f"error: interrupted (Ctrl-C); {said}", file=sys.stderr)
            sys.exit(EXIT_INTERRUPTED)
        except Exception as exc:
            expected = _expected(exc)
            if expected is None or debugging():
                raise
            print(f"error: {_message(expected)}", file=sys.stderr)
            sys.exit(EXIT_INPUT_ERROR)

    return run


def composition_message(exc: BaseException) -> str:
    """Hydra's (or OmegaConf's) several-line composition error as one line: the problem and the
    fix it suggests, the available options listed inline, the search path left out."""
    key = getattr(exc, "full_key", None)
    if isinstance(exc, MissingMandatoryValue) and key:
        return f"{key}: no value (??? in the config); set it on the command line: {key}=..."
    parts: list[str] = []
    listing = False  # inside "Available options in 'model':" (one option per line)
    for raw in str(exc).splitlines():
        line = raw.strip()
        if line.startswith(("Config search path", "Set the environment variable")):
            break
        if not line or line.startswith(("full_key:", "object_type=", "reference_type=")):
            continue
        if listing and raw.startswith("\t"):
            parts[-1] += (" " if parts[-1].endswith(":") else ", ") + line
            continue
        listing = line.endswith(":")
        parts.append(line)
    text = " ".join(p if p.endswith((".", ":")) else p + ";" for p in parts).rstrip(";")
    if key and key not in text:
        text = f"{key}: {text}"
    return text.replace("See https", "see https") or type(exc).__name__


def task_overrides() -> list[str]:
    """The command line's ``key=value`` overrides of the running Hydra job (one job's, in a
    multirun); an empty list outside a Hydra app."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return []
    return list(HydraConfig.get().overrides.task)


def _group_overrides(overrides: list[str]) -> list[str]:
    """The overrides that choose a config group (``model=v1``, ``+experiment=finetune``): a key
    that names a folder of ``conf/``."""
    chosen = []
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~").split("@")[0]
        if "=" in override and key and (CONF_DIR / key).is_dir():
            chosen.append(override)
    return chosen


def check_booleans(cfg, reference) -> None:
    """Refuse a value other than true/false for an option whose default is true or false
    (``overwrite=no``, ``wall_guard=flase``: non-empty strings, which Python takes as true),
    and a ``threads`` that is not a whole number >= 1.

    Args:
        cfg: the composed config of the run.
        reference: the same config composed with only the command line's group choices (the
            defaults of every option).

    Raises:
        InputError: naming the option, the value and the two values it takes.
    """
    defaults = flatten(OmegaConf.to_container(reference, resolve=False))
    for key, default in defaults.items():
        if not isinstance(default, bool) or key in NOT_ONLY_BOOLEAN or key.startswith("hydra."):
            continue
        value = OmegaConf.select(cfg, key, default=default, throw_on_missing=False)
        if not isinstance(value, bool):
            raise InputError(
                f"{key}: expected true or false, got {value!r}; write {key}=true or {key}=false"
            )
    if "threads" in cfg and not OmegaConf.is_missing(cfg, "threads"):
        whole_number("threads", cfg.threads, minimum=1)


def _check_run_folder(cfg) -> None:
    """Refuse a run folder (``hydra.run.dir``) that cannot be created, before Hydra tries."""
    try:
        folder = Path(str(cfg.hydra.run.dir))
    except Exception:  # an interpolation only the run resolves: Hydra reports its own
        return
    existing = folder.absolute()
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.is_dir() and not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(
            f"hydra.run.dir: cannot create the run folder {folder} ({existing} is not writable); "
            "run from a writable folder or pass hydra.run.dir=<a writable folder>"
        )
    free = shutil.disk_usage(existing).free if existing.is_dir() else RUN_FOLDER_MIN_FREE
    if free < RUN_FOLDER_MIN_FREE:
        raise InputError(
            f"hydra.run.dir: only {free / 2**20:.0f} MiB free for the run folder {folder}; free "
            "some space or pass hydra.run.dir=<a folder on another disk>"
        )


def _non_ascii_message(argv: list[str]) -> str | None:
    """The fix for an override Hydra's lexer refused because of a character it does not take
    unquoted (``trajectory=/tmp/données/x.h5``), or None."""
    for arg in argv:
        odd = [c for c in arg if ord(c) > 127]
        if odd and "=" in arg and not any(q in arg for q in "'\""):
            key, value = arg.split("=", 1)
            return (
                f"{key}: Hydra's command-line syntax does not take {odd[0]!r} unquoted in "
                f"{value!r}; quote the value: '{key}=\"{value}\"'"
            )
    return None


_PRECHECKED = {"done": False}


def _refuse_set_for_you(overrides: list[str]) -> None:
    """Exit 2 with one ``error:`` line naming what sets it when an override sets a key of
    :data:`SET_FOR_YOU` (with or without ``+``/``~``, on a single run or a ``--multirun``)."""
    for arg in overrides:
        key = arg.split("=", 1)[0].lstrip("+~")
        if key in SET_FOR_YOU:
            print(f"error: {key}: not a setting: {SET_FOR_YOU[key]}", file=sys.stderr)
            sys.exit(EXIT_INPUT_ERROR)


def _precheck(config_name: str, argv: list[str]) -> None:
    """Compose ``argv``'s overrides once and report a failure as one ``error:`` line, exit 2.
    Skipped for Hydra's flags (``--multirun``, ``--help``, ``--cfg``...), which Hydra handles."""
    if any(arg.startswith("-") for arg in argv) or debugging():
        return
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        return
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            cfg = hydra_compose(config_name=config_name, overrides=argv, return_hydra_config=True)
            reference = hydra_compose(config_name=config_name, overrides=_group_overrides(argv))
        for key in cfg:  # interpolations that resolve before the run (not the run folder's)
            if key != "hydra":
                try:
                    node = cfg[key]
                    if OmegaConf.is_config(node):
                        OmegaConf.to_container(node, resolve=True)
                except InterpolationResolutionError as exc:
                    if "hydra" not in str(exc).lower():
                        raise
        check_booleans(cfg, reference)
        _check_run_folder(cfg)
    except (HydraException, OmegaConfBaseException) as exc:
        parse = type(exc).__name__ == "OverrideParseException"
        message = _non_ascii_message(argv) if parse else None
        print(f"error: {message or composition_message(exc)}", file=sys.stderr)
        sys.exit(EXIT_INPUT_ERROR)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(EXIT_INPUT_ERROR)
    _PRECHECKED["done"] = True


def _in_app_check(config_name: str, cfg) -> None:
    """:func:`check_booleans` inside the Hydra job, when :func:`_precheck` was skipped (a
    ``--multirun``, or a call with flags): one job's overrides."""
    from hydra import compose as hydra_compose
    from hydra.core.global_hydra import GlobalHydra

    if _PRECHECKED["done"] or not GlobalHydra.instance().is_initialized():
        return

    reference = hydra_compose(config_name=config_name, overrides=_group_overrides(task_overrides()))
    check_booleans(cfg, reference)


def command(config_name: str) -> Callable[[Callable], Callable]:
    """Decorate ``main(cfg)`` as the Hydra entry point over ``conf/<config_name>.yaml``, with
    :func:`reports_errors`; a command line that does not compose is refused first."""

    def decorate(func: Callable) -> Callable:
        app = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name=config_name)

        @functools.wraps(func)
        def checked(cfg, *args, **kwargs):
            _in_app_check(config_name, cfg)
            return func(cfg, *args, **kwargs)

        hydra_main = app(reports_errors(checked))

        @functools.wraps(func)
        def run(*args, **kwargs):
            if not args and not kwargs:  # from the command line
                _refuse_set_for_you(sys.argv[1:])
                _precheck(config_name, sys.argv[1:])
                keep_freed_memory()
            return hydra_main(*args, **kwargs)

        return run

    return decorate
