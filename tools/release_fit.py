"""``python -m tools.release_fit <ckpt> [--share 0.25] [--steps 200] [--lr 5e-4] [--wall-sum]``
(from the checkout's root): can a model learn to let a bed at rest go when its lid is removed,
while keeping a bed on a closed lid at rest?

A small fit, not a training run: windows whose history is at rest (95% of the particles under
1 mm/s) are taken from ``wedge_rest`` training runs 0-3 of ``data/hoppers``; "release" windows
hold the lid's removal (``WindowDataset.event_windows``), "rest" windows do not. A mix with
``--share`` release windows is built once through the training collate (offset noise 0.5 mm,
a quarter clean, rest weight 30, reach mask, as the equivariant hopper arms), and the model
(raw weights with ``--raw``; ``--wall-sum`` switches the equivariant processor's wall sum on,
zero weights) is fitted with Adam, batch 4, on the acceleration's loss (ungated) plus, with a
rest gate, the gate's hinge. Every 50 steps the bottom layer (within 4 mm of the lowest
centre) of ``data/hoppers/wedge/traj_0011.h5``'s release and rest windows is read: the mean
vertical acceleration (m/s^2, ungated) and the median gate logit (shut at -1 or below).
LIGGGHTS's release windows fall at 0-5.5 m/s^2 (2.3 mean); at rest, 0.
"""

from __future__ import annotations

import argparse
import random

import numpy as np
import torch

from granular_pyg.checkpoint.files import read_checkpoint
from granular_pyg.checkpoint.fine_tune import with_wall_sum
from granular_pyg.checkpoint.model import build_model, load_weights
from granular_pyg.data.windows import WindowDataset
from granular_pyg.inference import load_simulator
from granular_pyg.nn.rest_gate import gate_hinge
from granular_pyg.training.data_module import _Collate, at_rest
from tools.release_response import BOTTOM_LAYER_M, raw_weights

TRAIN = [f"data/hoppers/wedge_rest/traj_000{i}.h5" for i in range(4)]
TEST = "data/hoppers/wedge/traj_0011.h5"


def _windows(sim, files: list[str], k: int) -> tuple[list, list]:
    """(release, rest) windows of ``files`` whose history is at rest."""
    data = WindowDataset(files, history=sim.history, frames_per_step=k)
    events, release, rest = set(data.event_windows()), [], []
    for i in range(len(data)):
        w = data[(0, i)]
        if float(at_rest(w.pos_seq, float(sim.dt)).float().mean()) > 0.95:
            (release if i in events else rest).append(w)
    return release, rest


def _bottom(w) -> torch.Tensor:
    z = w.pos_seq[:, -1, 2]
    return z < z.min() + BOTTOM_LAYER_M


def _read(sim, windows) -> tuple[float, float]:
    """Mean over ``windows`` of the bottom layer's mean a_z (m/s^2, ungated) and median gate
    logit."""
    acc, gate = [], []
    with torch.no_grad():
        for w in windows:
            out = sim._network_output(sim.build_graph(w.pos_seq, w.walls, w.time, props=w.props))
            low = _bottom(w)
            acc.append(float((out[low, 2] * sim.acc_std[2] + sim.acc_mean[2]).mean()))
            gate.append(float(out[low, 3].median()) if out.shape[1] > 3 else float("nan"))
    return float(np.mean(acc)), float(np.mean(gate))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ckpt")
    parser.add_argument("--share", type=float, default=0.25, help="release windows in the mix")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--lr", type=float, default=5e-4)
    parser.add_argument("--raw", action="store_true", help="the raw weights, not the EMA")
    parser.add_argument("--wall-sum", action="store_true", help="switch the wall sum on")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    random.seed(0)
    path = raw_weights(args.ckpt) if args.raw else args.ckpt
    sim, cfg = load_simulator(path)
    if args.wall_sum:
        model = dict(cfg["model"])
        model["processor"] = dict(model["processor"]) | {"wall_sum": True}
        state = read_checkpoint(path, "ckpt")[1]["state_dict"]
        state = with_wall_sum(state, int(model["latent"]))
        sim = build_model(model | {"dt": float(sim.dt)}, args.ckpt, state)
        load_weights(sim, {"state_dict": state}, args.ckpt)
    k = int(cfg["data"]["frames_per_step"])
    release, rest = _windows(sim, TRAIN, k)
    others = round(len(release) * (1 - args.share) / args.share)
    collate = _Collate(
        sim, 5e-5, 0, offset_std=5e-4, mask_beyond_reach=True, rest_weight=30.0, clean_share=0.25
    )
    batches = [collate([w]) for w in release + random.sample(rest, min(others, len(rest)))]
    test = _windows(sim, [TEST], k)
    test = (test[0], test[1][::10])

    def report(tag: str) -> None:
        sim.eval()
        (ra, rg), (sa, sg) = (_read(sim, ws) for ws in test)
        sim.train()
        print(f"{tag}: release a_z {ra:6.2f} gate {rg:6.2f} | rest a_z {sa:6.2f} gate {sg:6.2f}")

    report("before")
    sim.train()
    opt = torch.optim.Adam(sim.parameters(), lr=args.lr)
    for step in range(1, args.steps + 1):
        opt.zero_grad()
        loss = torch.zeros(())
        for g in random.sample(batches, 4):
            pred, logits = sim.forward_with_gate(g)
            ok = torch.isfinite(g.y).all(dim=1)
            loss = loss + (g.weight[ok, None] * (pred[ok] - g.y[ok]) ** 2).mean()
            if logits is not None:
                loss = loss + gate_hinge(logits, g.gate_label)
        loss.backward()
        opt.step()
        if step % 50 == 0:
            report(f"step {step}")


if __name__ == "__main__":
    main()
