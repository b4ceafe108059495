"""Moved to :mod:`granular_pyg.checkpoint.card` (one module owns the checkpoint); kept
so that older imports work."""

from granular_pyg.checkpoint.card import *  # noqa: F403
from granular_pyg.checkpoint.card import __all__  # noqa: F401
