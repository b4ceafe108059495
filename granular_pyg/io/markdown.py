"""Markdown tables and the ``Command: `python -m ...``` line that every report starts with.

One definition of the table layout (``| a | b |`` over ``|---|---:|``) and of the recorded
command line, shared by the evaluation, experiment, benchmark and stress reports.
"""

from __future__ import annotations

import numbers
import sys
from collections.abc import Sequence
from typing import Any

__all__ = ["command_header", "command_line", "format_cell", "markdown_table"]

#: The rule under the header for each alignment: left (default), right, centre.
_RULES = {"l": "---", "r": "---:", "c": ":---:"}


def format_cell(value: Any) -> str:
    """One table cell as text.

    Returns:
        ``""`` for ``None``; a string unchanged; ``"True"``/``"False"`` for a bool; an integer
        in plain digits (no thousands separators: format it yourself, e.g. ``f"{n:,}"``, where
        a table wants them); any other real number (float, NumPy float) as ``f"{value:.4g}"``
        (so NaN is ``"nan"``); anything else as ``str(value)``.
    """
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, numbers.Integral)):
        return str(value)
    if isinstance(value, numbers.Real):
        return f"{float(value):.4g}"
    return str(value)


def markdown_table(
    columns: Sequence[str], rows: Sequence[Sequence[Any]], align: Sequence[str] | str | None = None
) -> str:
    """A Markdown (GitHub) table.

    Args:
        columns: the header cells.
        rows: one sequence of cell values per row, as long as ``columns``; each cell is
            formatted by :func:`format_cell` (pass strings to format a column yourself).
        align: per column ``"l"`` (``---``, the default), ``"r"`` (``---:``) or ``"c"``
            (``:---:``), as a sequence or a string such as ``"lrr"``; None: all left.

    Returns:
        The header line, the rule line and one line per row, joined with ``"\\n"`` (no
        trailing newline), e.g. ``"| a | b |\\n|---|---:|\\n| x | 1 |"``. With no rows: the
        header and the rule only.

    Raises:
        ValueError: ``align`` or a row does not have one entry per column, or an unknown
            alignment letter.
    """
    columns = [str(c) for c in columns]
    align = ["l"] * len(columns) if align is None else list(align)
    if len(align) != len(columns):
        raise ValueError(f"align has {len(align)} entries for {len(columns)} columns")
    unknown = sorted(set(align) - set(_RULES))
    if unknown:
        raise ValueError(f"unknown alignment {unknown}: use 'l', 'r' or 'c'")
    lines = [_line(columns), "|" + "|".join(_RULES[a] for a in align) + "|"]
    for i, row in enumerate(rows):
        cells = [format_cell(v) for v in row]
        if len(cells) != len(columns):
            raise ValueError(f"row {i} has {len(cells)} cells for {len(columns)} columns")
        lines.append(_line(cells))
    return "\n".join(lines)


def _line(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def command_line(module: str, argv: Sequence[str] | None = None) -> str:
    """The command that ran ``module``, as a user would type it.

    Args:
        module: the dotted module name, e.g. ``"granular_pyg.bench"``.
        argv: the arguments; None: this process's ``sys.argv[1:]``.

    Returns:
        ``"python -m <module> <argv joined by spaces>"`` with surrounding whitespace stripped,
        e.g. ``"python -m granular_pyg.bench suite=geometry"`` (``"python -m <module>"`` with
        no arguments).
    """
    args = sys.argv[1:] if argv is None else argv
    return ("python -m " + module + " " + " ".join(args)).strip()


def command_header(module: str, argv: Sequence[str] | None = None) -> str:
    """The ``Command:`` line of a report.

    Returns:
        ``"Command: `<command_line(module, argv)>`"`` (one line, no trailing newline).
    """
    return f"Command: `{command_line(module, argv)}`"
