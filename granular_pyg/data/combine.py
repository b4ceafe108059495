"""``python -m granular_pyg.data.combine data/general --hold-out cone``: one dataset over
several geometry families.

Each sub-folder of the root is one family's dataset, made by ``generate`` (for example
``+dem_dataset=general_cone`` writes ``data/general/cone``). The root's ``manifest.json`` lists
every family's trajectories (paths relative to the root) in the families' own train / valid /
test splits; a held-out family's trajectories all go to the split ``heldout``, so a model
trained on the root never sees them and ``evaluate 'splits=[test,heldout]'`` reports the
in-distribution and the held-out family side by side.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path

from granular_pyg.cli import reports_errors
from granular_pyg.errors import InputError
from granular_pyg.io import atomic_write

__all__ = ["SPLITS", "combine", "main"]

#: The splits of a combined manifest.
SPLITS = ("train", "valid", "test", "heldout")


def combine(root: str | Path, hold_out: Sequence[str] = ()) -> Path:
    """Write ``root/manifest.json`` over the family datasets in ``root``'s sub-folders.

    Args:
        root: a folder whose sub-folders hold one ``generate`` dataset each.
        hold_out: families whose trajectories go to the ``heldout`` split only.

    Returns:
        The manifest's path.

    Raises:
        InputError: no family dataset, a held-out family that is not there, a family listed
            twice, a file of a manifest that is missing, or nothing left to train on.
    """
    root = Path(root)
    parts = sorted(p.parent for p in root.glob("*/manifest.json"))
    if not parts:
        raise InputError(
            f"{root}: no family datasets (sub-folders with a manifest.json); make them with "
            "`python -m granular_pyg.generate +dem_dataset=general_<family>`"
        )
    splits: dict[str, list[str]] = {s: [] for s in SPLITS}
    entries, families = [], {}
    for folder in parts:
        manifest = json.loads((folder / "manifest.json").read_text())
        family = str(manifest.get("family") or folder.name)
        if family in families:
            raise InputError(
                f"family {family!r} is in both {families[family]['folder']} and {folder.name}"
            )
        held = family in hold_out
        families[family] = {"folder": folder.name, "held_out": held, "scene": manifest.get("scene")}
        for split, files in manifest["splits"].items():
            for name in files:
                if not (folder / name).is_file():
                    raise InputError(
                        f"{folder / name}: listed in {folder / 'manifest.json'} but missing; "
                        f"complete it with the generate command that made {folder}"
                    )
                splits["heldout" if held else split].append(f"{folder.name}/{name}")
        for entry in manifest.get("trajectories", []):
            entries.append(entry | {"file": f"{folder.name}/{entry['file']}", "family": family})
    missing = sorted(set(hold_out) - set(families))
    if missing:
        raise InputError(f"--hold-out: no family {missing} in {root}; it has {sorted(families)}")
    if not splits["train"]:
        raise InputError(
            f"{root}: no training trajectory is left after holding out {list(hold_out)}"
        )
    path = root / "manifest.json"
    with atomic_write(path) as fh:
        json.dump({"families": families, "splits": splits, "trajectories": entries}, fh, indent=1)
    return path


@reports_errors
def main(argv: Sequence[str] | None = None) -> Path:
    """Command line; see the module docstring."""
    parser = argparse.ArgumentParser(
        prog="python -m granular_pyg.data.combine", description=__doc__.splitlines()[0]
    )
    parser.add_argument("root", type=Path, help="folder of family datasets (sub-folders)")
    parser.add_argument("--hold-out", nargs="*", default=[], help="families to hold out")
    args = parser.parse_args(argv)
    path = combine(args.root, args.hold_out)
    manifest = json.loads(path.read_text())
    counts = ", ".join(f"{s} {len(f)}" for s, f in manifest["splits"].items())
    print(f"{len(manifest['families'])} families ({counts} trajectories): {path}")
    return path


if __name__ == "__main__":
    main()
