"""A small copy of a dataset's train and valid splits for a training run on a lent GPU machine.

The device tool carries at most 64 MiB with the working tree, and our datasets are 250-350 MB.
Training reads positions only (velocities are finite differences of them), so the copy keeps
every ``every``-th frame of the positions, bit for bit, and writes the velocities as zeros (NaN
where the particle has left). Train on it with ``data.frames_per_step`` divided by ``every``: the
same learned step, fewer of its frame offsets.

    python tools/device_copy.py data/hoppers .device/hoppers --every 4
    python -m granular_pyg.train +experiment=equivariant_hopper data.root=.device/hoppers \
        data.frames_per_step=4 init=runs/equivariant_hopper/last.ckpt trainer.accelerator=gpu
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from granular_pyg.io import Trajectory, read_trajectory, write_trajectory

SPLITS = ("train", "valid")


def thin(source: Path, out: Path, every: int) -> int:
    """Write the thinned copy of ``source``'s train and valid splits to ``out``; returns bytes."""
    manifest = json.loads((source / "manifest.json").read_text())
    kept = {split: manifest["splits"][split] for split in SPLITS}
    for name in (n for names in kept.values() for n in names):
        traj = read_trajectory(source / name)
        pos = traj.positions[::every]
        vel = np.where(np.isnan(pos), np.float32(np.nan), np.float32(0.0))
        small = Trajectory(
            positions=pos,
            velocities=vel,
            radii=traj.radii,
            ids=traj.ids,
            times=traj.times[::every],
            scene=traj.scene,
            metadata=traj.metadata,
        )
        write_trajectory(small, out / name, compression="gzip", level=9)
    (out / "manifest.json").write_text(json.dumps({**manifest, "splits": kept}, indent=1))
    return sum(f.stat().st_size for f in out.rglob("*") if f.is_file())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--every", type=int, required=True, help="keep every n-th frame")
    args = parser.parse_args()
    size = thin(args.source, args.out, args.every)
    print(f"{args.out}: {size / 2**20:.1f} MiB")


if __name__ == "__main__":
    main()
