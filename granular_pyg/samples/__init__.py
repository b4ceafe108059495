"""The bundled LIGGGHTS samples (package data): 4 hopper and 4 drum trajectories.

Regenerate them with ``python -m granular_pyg.generate +dem_dataset=sample_hopper`` and
``+dem_dataset=sample_drum`` (configs in ``conf/dem_dataset/``).
"""

from __future__ import annotations

import json
from pathlib import Path

from granular_pyg.errors import InputError

__all__ = ["SAMPLES_DIR", "sample_dir", "sample_files"]

SAMPLES_DIR = Path(__file__).resolve().parent


def sample_dir(scene: str) -> Path:
    """Folder of the bundled sample of ``scene`` (``"hopper"`` or ``"drum"``)."""
    folder = SAMPLES_DIR / scene
    if not (folder / "manifest.json").is_file():
        known = sorted(p.name for p in SAMPLES_DIR.iterdir() if (p / "manifest.json").is_file())
        raise InputError(
            f"no bundled sample {scene!r} (have: {known}); regenerate it with "
            f"`python -m granular_pyg.generate +dem_dataset=sample_{scene}`"
        )
    return folder


def sample_files(scene: str, split: str | None = None) -> list[Path]:
    """Trajectory files of the bundled sample, optionally of one split (train/valid/test)."""
    folder = sample_dir(scene)
    manifest = json.loads((folder / "manifest.json").read_text())
    if split is None:
        names = [entry["file"] for entry in manifest["trajectories"]]
    elif split in manifest["splits"]:
        names = manifest["splits"][split]
    else:
        raise InputError(f"split: expected one of {sorted(manifest['splits'])}, got {split!r}")
    return [folder / name for name in names]
