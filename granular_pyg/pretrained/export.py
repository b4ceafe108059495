"""``python -m granular_pyg.pretrained.export <ckpt> <name> --out <file>``: ship a trained
checkpoint.

Keeps the model's config and weights (drops the optimiser and loop state: a few hundred kB
instead of MBs), records what it was trained on, points its default test data at a bundled
sample, and writes the slim file atomically to ``--out``. It writes into the installed package
(``granular_pyg/pretrained/<name>_v3.ckpt``, replacing ``pretrained:<name>``) only when asked
with ``--overwrite`` and no ``--out``. The checkpoint is read safely
(:func:`granular_pyg.checkpoint.read_training_checkpoint`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from granular_pyg.checkpoint import (
    PREFIX,
    PRETRAINED,
    PRETRAINED_DIR,
    build_model,
    load_weights,
    read_training_checkpoint,
    resolve_checkpoint,
)
from granular_pyg.checkpoint.saved_config import migrate_config
from granular_pyg.cli import reports_errors
from granular_pyg.errors import InputError
from granular_pyg.io import atomic_path, check_output
from granular_pyg.samples import SAMPLES_DIR

#: Largest file the package ships (bytes).
MAX_BYTES = 10 * 2**20


def export(
    ckpt: str | Path,
    name: str,
    sample: str,
    note: str = "",
    folder: Path | None = None,
    out: str | Path | None = None,
    overwrite: bool = False,
    sleep: bool | None = None,
    canonical_frame: bool | None = None,
    wall_nodes: str | None = None,
) -> Path:
    """Write the slim copy of ``ckpt`` as the pretrained model ``name``; returns its path.

    Args:
        ckpt: a training checkpoint.
        name: one of :data:`PRETRAINED`'s names.
        sample: the bundled sample (``hopper`` or ``drum``) its rollouts default to.
        note: free text on how well it does (kept in the file).
        folder: write ``<folder>/<name>_v3.ckpt`` (tests; the package's folder needs
            ``overwrite``).
        out: the file to write (never ``ckpt``; an existing one only with ``overwrite``).
        overwrite: replace an existing output, the shipped ``pretrained:<name>`` included.
        sleep: set ``model.sleep`` (:mod:`granular_pyg.sleep`, a rule without weights) in the
            shipped config; None keeps the checkpoint's. A shipped model given as ``ckpt``
            keeps its record (source, steps, training data, note unless a new one is given).
        canonical_frame: set ``model.canonical_frame`` (the scene's own frame, no weights)
            likewise; None keeps the checkpoint's.
        wall_nodes: set ``model.wall_nodes`` (``patch``: a node per surface patch, the same
            for any triangulation; ``triangle``) likewise; None keeps the checkpoint's.

    Raises:
        InputError: an unknown name, no output named, an unsafe, unreadable or non-training
            checkpoint, weights that do not fit its config, an output that exists without
            ``overwrite`` or is the input, a file too large to ship.
    """
    if name not in PRETRAINED:
        raise InputError(f"name: expected one of {sorted(PRETRAINED)}, got {name!r}")
    samples = sorted(p.name for p in SAMPLES_DIR.iterdir() if (p / "manifest.json").is_file())
    if sample not in samples:
        raise InputError(f"--sample: expected a bundled sample, one of {samples}, got {sample!r}")
    source = resolve_checkpoint(ckpt, "ckpt")
    path, full = read_training_checkpoint(source, "ckpt")  # the input's errors first
    if out is None and folder is None:
        if not overwrite:
            raise InputError(
                f"--out: not given; pass --out <file>.ckpt, or --overwrite to replace the "
                f"shipped {PREFIX}{name} inside the installed package ({PRETRAINED_DIR})"
            )
        folder = PRETRAINED_DIR
    target = Path(out) if out is not None else Path(folder) / PRETRAINED[name]
    target = check_output(
        target, [source], overwrite, option="--out", overwrite_option="--overwrite"
    )
    config = migrate_config(full["config"])  # today's keys: an older model ships as it was
    if wall_nodes not in (None, "patch", "triangle"):
        raise InputError(f"--wall-nodes: expected patch or triangle, got {wall_nodes!r}")
    rules = {"sleep": sleep, "canonical_frame": canonical_frame, "wall_nodes": wall_nodes}
    for key, value in rules.items():
        if value is not None:
            config["model"] = dict(config["model"]) | {key: value}
    built = build_model(config["model"], f"ckpt: {path}", full["state_dict"])
    load_weights(built, full, f"ckpt: {path}")
    record = {
        "source": str(ckpt),
        "global_step": int(full.get("global_step", 0)),
        "trained_on": dict(config.get("data") or {}),
        "note": note,
    }
    if isinstance(full.get("pretrained"), dict):  # a shipped model: its record stands
        record = full["pretrained"] | ({"note": note} if note else {})
    config["data"] = dict(record["trained_on"]) | {"root": None, "sample": sample}
    slim = {
        "config": config,
        "state_dict": {k: v for k, v in full["state_dict"].items() if k.startswith("sim.")},
        "model_card": full.get("model_card") or {},
        "pretrained": record,
    }
    with atomic_path(target) as tmp:
        torch.save(slim, tmp)
        if tmp.stat().st_size > MAX_BYTES:
            raise InputError(f"{ckpt}: {tmp.stat().st_size} bytes, over the 10 MB a package ships")
    return target


@reports_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ckpt")
    parser.add_argument("name", choices=sorted(PRETRAINED))
    parser.add_argument("--sample", default=None, help="bundled sample (default: the name)")
    parser.add_argument("--note", default="")
    parser.add_argument("--out", default=None, help="the slim checkpoint to write (.ckpt)")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing --out; without --out: replace the shipped pretrained:<name>",
    )
    parser.add_argument(
        "--sleep",
        choices=["true", "false"],
        default=None,
        help="set model.sleep in the shipped config (default: the checkpoint's)",
    )
    parser.add_argument(
        "--canonical-frame",
        choices=["true", "false"],
        default=None,
        help="set model.canonical_frame in the shipped config (default: the checkpoint's)",
    )
    parser.add_argument(
        "--wall-nodes",
        choices=["patch", "triangle"],
        default=None,
        help="set model.wall_nodes in the shipped config (default: the checkpoint's)",
    )
    args = parser.parse_args(argv)
    sleep = None if args.sleep is None else args.sleep == "true"
    canonical = None if args.canonical_frame is None else args.canonical_frame == "true"
    out = export(
        args.ckpt,
        args.name,
        args.sample or args.name,
        args.note,
        None,
        args.out,
        args.overwrite,
        sleep,
        canonical,
        args.wall_nodes,
    )
    print(f"pretrained model: {out} ({out.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
