"""tools.results_section: a run's own files replace one section of results.md, nothing else."""

from __future__ import annotations

import json

import pytest

from tools.results_section import main, replace_section

DOC = """# Results

## Speed

### Geometry

2026-01-01, old numbers.

| a |
|---|
| 1 |

### Scaling

kept as it is

## What did not help

kept too
"""


def _run_folder(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    record = {"x": 1.0, "machine": {"cpu_count": 2}, "commit": "abc123", "command": "python -m b"}
    (folder / "results.json").write_text(json.dumps(record))
    (folder / "report.md").write_text(
        "# Benchmark `geometry`\n\nCommand: `python -m b`\n\nCommit `abc123`, machine: x\n\n"
        "| speed-up |\n|---|\n| 127x |\n\n## Targets\n\n| t |\n|---|\n"
    )
    return folder


def test_a_rerun_replaces_its_section_and_keeps_the_rest(tmp_path):
    results = tmp_path / "results.md"
    results.write_text(DOC)
    folder = _run_folder(tmp_path)
    main([str(folder), "### Geometry", "--results", str(results)])
    once = results.read_text()
    assert "old numbers" not in once and "| 127x |" in once
    assert "commit `abc123`:\n`python -m b`" in once and "#### Targets" in once
    assert once.split("### Scaling")[1] == DOC.split("### Scaling")[1]
    assert once.split("### Geometry")[0] == DOC.split("### Geometry")[0]
    main([str(folder), "### Geometry", "--results", str(results)])
    assert results.read_text() == once  # a rerun replaces, never appends


def test_an_unknown_section_or_folder_is_refused(tmp_path):
    with pytest.raises(KeyError, match="no section"):
        replace_section(DOC, "### Nowhere", "x")
    with pytest.raises(FileNotFoundError):
        main([str(tmp_path), "### Geometry", "--dry-run"])
