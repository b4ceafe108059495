"""Hydra helpers: where the configs are, and composing one from code or from inside an app."""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

__all__ = ["CONF_DIR", "compose"]

#: The top-level ``conf/`` folder (found from a checkout or an editable install).
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def compose(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides``, inside a running Hydra app (which
    has already loaded ``conf/``) or from plain code (tests, notebooks)."""
    if GlobalHydra.instance().is_initialized():
        return hydra.compose(config_name=config_name, overrides=overrides or [])
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return hydra.compose(config_name=config_name, overrides=overrides or [])
