"""Hydra helpers: where the configs are, and composing one from code or from inside an app.

The configs live in the checkout's top-level ``conf/``; a wheel carries the same files as
``granular_pyg/conf`` (``pyproject.toml`` maps one onto the other). A checkout's ``conf/`` wins,
so that edits there take effect.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

__all__ = ["CONF_DIR", "compose", "find_conf_dir", "flatten"]


def find_conf_dir() -> Path:
    """The config folder: the checkout's ``conf/`` (a checkout or an editable install), else the
    copy installed with the package (``granular_pyg/conf`` in a wheel)."""
    package = Path(__file__).resolve().parent
    for folder in (package.parent / "conf", package / "conf"):
        if (folder / "train.yaml").is_file():
            return folder
    raise FileNotFoundError(
        f"granular_pyg's configs are missing: neither {package.parent / 'conf'} nor "
        f"{package / 'conf'} holds train.yaml; reinstall the package (pip install .)"
    )


#: The config folder every command and :func:`compose` read.
CONF_DIR = find_conf_dir()


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides``, inside a running Hydra app (which
    has already loaded ``conf/``) or from plain code (tests, notebooks)."""
    if GlobalHydra.instance().is_initialized():
        return hydra.compose(config_name=config_name, overrides=overrides or [])
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return hydra.compose(config_name=config_name, overrides=overrides or [])


def flatten(tree, prefix: str = "") -> dict:
    """A nested dict as ``{"a.b.c": leaf}`` (a non-dict ``tree`` is ``{prefix: tree}``), to
    name the keys in which two configs differ."""
    if not isinstance(tree, dict):
        return {prefix: tree}
    out = {}
    for key, value in tree.items():
        out |= flatten(value, f"{prefix}.{key}" if prefix else str(key))
    return out
