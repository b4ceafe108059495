"""Hostile checkpoint files for the safety tests: each would make a marker file if the code
that reads it ran anything the file names.

- :func:`pickle_payload`: a checkpoint whose pickle names ``builtins.exec`` (``__reduce__``),
  run by ``torch.load(weights_only=False)``;
- :func:`config_target`: a clean pickle (the shipped hopper's) whose saved config names another
  ``_target_`` than a model class: ``builtins.open``, ``pathlib.Path.write_text``, or
  ``torch.load`` of a pickle payload (full code execution again), at the top or nested.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch

from granular_pyg.checkpoint import resolve_checkpoint, safe_load


class _Payload:
    """Pickles as a call of ``exec`` that creates ``marker``."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return exec, (f"open({self.marker!r}, 'w').write('ran')",)


def shipped(name: str = "hopper") -> dict:
    """The contents of ``pretrained:<name>``, read safely."""
    return safe_load(resolve_checkpoint(f"pretrained:{name}"))


def pickle_payload(path: Path, marker: Path) -> Path:
    """A real checkpoint (the shipped hopper's contents) with a pickle payload inside."""
    ckpt = shipped()
    ckpt["pretrained"] = {"note": _Payload(marker)}
    torch.save(ckpt, path)
    return path


def config_target(path: Path, marker: Path, how: str = "open", nested: bool = False) -> Path:
    """The shipped hopper with its model ``_target_`` (or, ``nested``, its processor's) replaced
    by a call that creates ``marker``: ``how`` is ``open`` (``builtins.open(marker, "w")``),
    ``write_text`` (``pathlib.Path.write_text``) or ``torch.load`` (of a pickle payload)."""
    ckpt = shipped()
    if how == "open":
        node = {"_target_": "builtins.open", "_args_": [str(marker), "w"]}
    elif how == "write_text":
        node = {"_target_": "pathlib.Path.write_text", "_args_": [str(marker), "ran"]}
    elif how == "torch.load":
        inner = pickle_payload(path.with_name(path.stem + "_inner.ckpt"), marker)
        node = {"_target_": "torch.load", "f": str(inner), "weights_only": False}
    else:
        raise ValueError(how)
    model = copy.deepcopy(ckpt["config"]["model"])
    if nested:
        model["processor"] = node
    else:
        model = node
    ckpt["config"]["model"] = model
    torch.save(ckpt, path)
    return path
