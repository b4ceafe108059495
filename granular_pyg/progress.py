"""Progress bars in a terminal, quiet logs in a file.

Every bar in the package (LIGGGHTS runs, rollouts, exports, training) asks :func:`show_progress`,
so a command piped into a log file writes its result lines, not one progress line per update.
"""

from __future__ import annotations

import sys
from typing import TextIO

__all__ = ["show_progress"]


def show_progress(requested: bool = True, stream: TextIO | None = None) -> bool:
    """Whether to draw a progress bar: ``requested`` and ``stream`` (default: standard error,
    where tqdm draws) is a terminal."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return bool(requested) and bool(isatty and isatty())
