"""The shared Markdown table and command-line helpers."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from granular_pyg.io import command_header, command_line, markdown_table
from granular_pyg.io.markdown import format_cell


def test_a_two_by_two_table_with_alignment():
    table = markdown_table(["name", "value"], [["a", "1"], ["b", "2"]], align=["l", "r"])
    assert table == "| name | value |\n|---|---:|\n| a | 1 |\n| b | 2 |"


def test_alignment_as_a_string_and_centred():
    table = markdown_table(["x", "y", "z"], [["1", "2", "3"]], align="lrc")
    assert table.splitlines()[1] == "|---|---:|:---:|"


def test_default_alignment_is_left():
    assert markdown_table(["a", "b"], [["x", "y"]]) == "| a | b |\n|---|---|\n| x | y |"


def test_floats_ints_and_other_cells_are_formatted():
    table = markdown_table(
        ["float", "small", "int", "big int", "numpy", "bool", "none", "nan", "str"],
        [[0.123456789, 1.5e-7, 3, 1234567, np.float32(2.5), True, None, float("nan"), "1.0"]],
    )
    assert table.splitlines()[2] == (
        "| 0.1235 | 1.5e-07 | 3 | 1234567 | 2.5 | True |  | nan | 1.0 |"
    )


def test_format_cell():
    assert format_cell(1234.5678) == "1235"
    assert format_cell(np.int64(12000)) == "12000"
    assert format_cell(f"{12000:,}") == "12,000"  # thousands separators: format it yourself
    assert format_cell(np.float64(0.5)) == "0.5"


def test_empty_rows_give_header_and_rule_only():
    assert markdown_table(["a", "b"], [], align="rc") == "| a | b |\n|---:|:---:|"


def test_empty_string_cells_keep_two_spaces():
    assert markdown_table(["a", "b"], [["", "x"]]).splitlines()[2] == "|  | x |"


@pytest.mark.parametrize(
    ("rows", "align"),
    [([["only one"]], None), ([["a", "b"]], "l"), ([["a", "b"]], "lx")],
)
def test_mismatched_rows_or_alignments_are_refused(rows, align):
    with pytest.raises(ValueError):
        markdown_table(["a", "b"], rows, align=align)


def test_command_line_with_a_given_argv():
    assert (
        command_line("granular_pyg.bench", ["suite=geometry", "repeats=3"])
        == "python -m granular_pyg.bench suite=geometry repeats=3"
    )


def test_command_line_without_arguments_is_stripped():
    assert command_line("granular_pyg.stress", []) == "python -m granular_pyg.stress"


def test_command_line_defaults_to_this_process_arguments(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/path/to/main.py", "quick=true", "out=/tmp/x"])
    assert (
        command_line("granular_pyg.stress") == "python -m granular_pyg.stress quick=true out=/tmp/x"
    )


def test_command_header():
    assert (
        command_header("granular_pyg.experiments.one_step_bias", ["ckpt=a.ckpt"])
        == "Command: `python -m granular_pyg.experiments.one_step_bias ckpt=a.ckpt`"
    )
