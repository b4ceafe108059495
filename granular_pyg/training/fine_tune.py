"""Moved to :mod:`granular_pyg.checkpoint.fine_tune` (one module owns the checkpoint); kept
so that older imports work."""

from granular_pyg.checkpoint.fine_tune import *  # noqa: F403
from granular_pyg.checkpoint.fine_tune import __all__  # noqa: F401
