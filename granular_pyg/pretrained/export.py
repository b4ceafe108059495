"""``python -m granular_pyg.pretrained.export <ckpt> <name>``: ship a trained checkpoint.

Keeps the model's config and weights (drops the optimiser and loop state: a few hundred kB
instead of MBs), records what it was trained on, points its default test data at a bundled
sample, and writes ``granular_pyg/pretrained/<name>_v3.ckpt`` atomically.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from granular_pyg.cli import reports_errors
from granular_pyg.errors import InputError
from granular_pyg.io import atomic_path
from granular_pyg.pretrained import PRETRAINED

#: Largest file the package ships (bytes).
MAX_BYTES = 10 * 2**20


def export(
    ckpt: str | Path, name: str, sample: str, note: str = "", folder: Path | None = None
) -> Path:
    """Write the slim copy of ``ckpt`` as the pretrained model ``name``; returns its path.

    Args:
        ckpt: a training checkpoint.
        name: one of :data:`PRETRAINED`'s names.
        sample: the bundled sample (``hopper`` or ``drum``) its rollouts default to.
        note: free text on how well it does (kept in the file).
        folder: where to write; default the package's ``pretrained/`` folder.
    """
    if name not in PRETRAINED:
        raise InputError(f"name: expected one of {sorted(PRETRAINED)}, got {name!r}")
    full = torch.load(ckpt, map_location="cpu", weights_only=False)
    config = full["config"]
    trained_on = dict(config["data"])
    config["data"] = trained_on | {"root": None, "sample": sample}
    slim = {
        "config": config,
        "state_dict": {k: v for k, v in full["state_dict"].items() if k.startswith("sim.")},
        "model_card": full.get("model_card") or {},
        "pretrained": {
            "source": str(ckpt),
            "global_step": int(full.get("global_step", 0)),
            "trained_on": trained_on,
            "note": note,
        },
    }
    out = Path(folder or Path(__file__).parent) / PRETRAINED[name]
    with atomic_path(out) as tmp:
        torch.save(slim, tmp)
        if tmp.stat().st_size > MAX_BYTES:
            raise InputError(f"{ckpt}: {tmp.stat().st_size} bytes, over the 10 MB a package ships")
    return out


@reports_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ckpt")
    parser.add_argument("name", choices=sorted(PRETRAINED))
    parser.add_argument("--sample", default=None, help="bundled sample (default: the name)")
    parser.add_argument("--note", default="")
    args = parser.parse_args(argv)
    out = export(args.ckpt, args.name, args.sample or args.name, args.note)
    print(f"pretrained model: {out} ({out.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
