"""``python -m tools.release_response <ckpt> <trajectory> [--raw]`` (from the checkout's root):
does a model let a bed at rest go when its support is removed?

A hopper's bed lies at rest on its lid; LIGGGHTS removes the lid at ``removal_time`` and the
bottom layer falls at once (5-9 m/s^2 within 40 ms). A learned step whose history is at rest
and whose walls over the step lack the lid must answer with that fall, or a rollout never
starts its discharge. For each learned step ending at frames from 2 steps before the removal
to 1 after, the bottom layer (centres within 4 mm of the lowest at frame 0) is read:

- ``ungated a_z``: the network's own vertical acceleration (m/s^2), the gate left out;
- ``gate``: the median gate logit and the share open (``g > -1``), for a model with
  ``rest_gate``;
- ``truth a_z``: LIGGGHTS's (m/s^2), from the frames a learned step apart.

``--raw``: a training checkpoint's raw weights instead of its weight average (the EMA lags by
about ``1 / (1 - decay)`` steps).
"""

from __future__ import annotations

import argparse
import os
import tempfile

import numpy as np
import torch

from granular_pyg.checkpoint.files import read_checkpoint
from granular_pyg.inference import load_simulator
from granular_pyg.io import read_trajectory
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import ParticleProps

BOTTOM_LAYER_M = 0.004


def raw_weights(path: str) -> str:
    """A copy of training checkpoint ``path`` whose weights are its raw ones (not the EMA)."""
    _, ckpt = read_checkpoint(path, "ckpt")
    if "raw_weights" not in ckpt:
        return path
    ckpt["state_dict"].update(ckpt.pop("raw_weights"))
    copy = os.path.join(tempfile.mkdtemp(), "raw.ckpt")
    torch.save(ckpt, copy)
    return copy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ckpt")
    parser.add_argument("trajectory", help="an HDF5 trajectory whose scene removes a wall")
    parser.add_argument("--raw", action="store_true", help="the raw weights, not the EMA")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sim, cfg = load_simulator(raw_weights(args.ckpt) if args.raw else args.ckpt)
    traj = read_trajectory(args.trajectory)
    walls = WallSet(traj.scene)
    removals = [w.removal_time for w in walls.walls if w.removal_time is not None]
    if not removals:
        raise SystemExit(f"{args.trajectory}: no wall of its scene is removed; give a hopper's")
    k, history = int(cfg["data"]["frames_per_step"]), sim.history
    frame_dt = traj.frame_dt
    removal = round(min(removals) / frame_dt)
    z0 = traj.positions[0, :, 2]
    bottom = z0 < np.nanmin(z0) + BOTTOM_LAYER_M
    props = ParticleProps.of(traj)
    print(f"{args.ckpt}: wall removed at {min(removals):.4f} s; bottom layer {int(bottom.sum())}")
    for last in range(removal - 2 * k, removal + k + 1, max(k // 4, 1)):
        if last - history * k < 0 or last + k >= len(traj.times):
            continue
        frames = [last - history * k + i * k for i in range(history + 1)]
        seq = torch.from_numpy(traj.positions[frames]).float().transpose(0, 1)
        if not torch.isfinite(seq).all():
            break
        with torch.no_grad():
            graph = sim.build_graph(seq, walls, float(traj.times[last]), props=props)
            out = sim._network_output(graph)
        acc = (out[:, :3] * sim.acc_std + sim.acc_mean).numpy()
        truth = traj.positions[last + k] - 2 * traj.positions[last] + traj.positions[last - k]
        truth_az = np.nanmean(truth[bottom, 2]) / (k * frame_dt) ** 2
        line = f"step from {traj.times[last]:.4f} s: ungated a_z {acc[bottom, 2].mean():6.2f}"
        if out.shape[1] > 3:
            g = out[bottom, 3].numpy()
            line += f"  gate median {np.median(g):6.2f}, open {np.mean(g > -1):.2f}"
        print(f"{line}  | truth a_z {truth_az:6.2f}")


if __name__ == "__main__":
    main()
