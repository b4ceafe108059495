"""Moved to :mod:`granular_pyg.checkpoint.saved_config` (one module owns the checkpoint); kept
so that older imports work."""

from granular_pyg.checkpoint.saved_config import *  # noqa: F403
from granular_pyg.checkpoint.saved_config import __all__  # noqa: F401
