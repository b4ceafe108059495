"""``python -m tools.results_section <run folder> "<section heading>"``: write one section of
``docs/results.md`` from a run's own files, replacing what the section held.

A bench run (``python -m granular_pyg.bench suite=...``) leaves ``results.json`` (command,
machine, commit) and ``report.md`` (its tables and targets) in its folder; an evaluation
(``python -m granular_pyg.evaluate``) leaves ``evaluation.json`` and ``report.md``. The section
named by its heading (``"### Geometry: wall-pair queries against the dense computation (BGNN)"``)
gets, under the heading, one line with the date, machine, commit and command, then the report's
body (its title, ``Command:`` and ``Commit`` lines left out). Everything up to the next heading
of the same or a higher level is replaced, so a rerun updates the section instead of adding to
the file; the rest of the file is kept byte for byte. ``--dry-run`` prints the new section.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results.md"


def run_record(folder: Path) -> dict:
    """``command``, ``machine`` (a line), ``commit`` and ``date`` of the run in ``folder``."""
    for name in ("results.json", "evaluation.json"):
        path = folder / name
        if path.is_file():
            data = json.loads(path.read_text())
            info = data.get("info", data)
            machine = info.get("machine") or {}
            if isinstance(machine, dict):
                machine = ", ".join(f"{v}" for v in machine.values() if v not in (None, ""))
            date = datetime.date.fromtimestamp(path.stat().st_mtime).isoformat()
            return {
                "command": info.get("command", "?"),
                "machine": machine or "?",
                "commit": info.get("commit", "?"),
                "date": date,
            }
    raise FileNotFoundError(f"{folder}: no results.json or evaluation.json")


def report_body(folder: Path) -> str:
    """``report.md`` without its title, ``Command:`` and ``Commit`` lines; headings demoted
    below the section's."""
    lines = (folder / "report.md").read_text().splitlines()
    kept = [
        line
        for line in lines
        if not line.startswith("# ") and not line.startswith(("Command: ", "Commit "))
    ]
    body = "\n".join(kept).strip()
    return re.sub(r"(?m)^(#{2,}) ", r"#\1## ", body)


def section_text(folder: Path) -> str:
    record = run_record(folder)
    head = (
        f"{record['date']}, {record['machine']}, commit `{record['commit']}`:\n"
        f"`{record['command']}`"
    )
    return f"{head}\n\n{report_body(folder)}\n"


def replace_section(text: str, heading: str, body: str) -> str:
    """``text`` with the body of the section ``heading`` (a whole line, ``## ...``) replaced."""
    level = len(heading) - len(heading.lstrip("#"))
    match = re.search(rf"(?m)^{re.escape(heading)}\n", text)
    if match is None:
        raise KeyError(f"no section {heading!r}")
    rest = text[match.end() :]
    end = re.search(rf"(?m)^#{{1,{level}}} ", rest)
    after = rest[end.start() :] if end else ""
    return text[: match.end()] + "\n" + body.rstrip("\n") + "\n" + ("\n" + after if after else "")


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="the run's output folder")
    parser.add_argument("heading", help='the section\'s heading line, e.g. "### Scaling"')
    parser.add_argument("--results", type=Path, default=RESULTS, help="the results file")
    parser.add_argument("--dry-run", action="store_true", help="print the section, write nothing")
    args = parser.parse_args(argv)
    body = section_text(args.folder)
    if args.dry_run:
        print(body)
        return body
    text = replace_section(args.results.read_text(), args.heading, body)
    args.results.write_text(text)
    print(f"{args.results}: {args.heading} rewritten from {args.folder}")
    return text


if __name__ == "__main__":
    main()
