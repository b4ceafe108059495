"""On a CUDA machine: the shipped fast models' rollouts on the GPU equal those on the CPU.

Rolls ``pretrained:fast_hopper`` and ``pretrained:fast_drum`` 10 steps over their bundled samples
on each device (float32, network alone, and with a Verlet skin) and prints the largest
position difference (m) and the GPU's steps per second; exits 1 if a difference exceeds 1e-4 m.

    python tools/cuda_rollout_check.py            (cpu against cuda)
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch

from granular_pyg.bench.trajectories import resolve_trajectory
from granular_pyg.inference import load_simulator, rollout_trajectory


def main(devices: tuple[str, str] = ("cpu", "cuda")) -> int:
    worst = 0.0
    for name, sample in (("fast_hopper", "hopper"), ("fast_drum", "drum")):
        truth = resolve_trajectory(f"sample:{sample}")
        for skin in (None, 0.001):
            out = {}
            for device in devices:
                sim, _ = load_simulator(f"pretrained:{name}", map_location=device)
                start = time.perf_counter()
                with torch.inference_mode():
                    pred = rollout_trajectory(sim, truth, steps=10, progress=False, skin=skin)
                if device.startswith("cuda"):
                    torch.cuda.synchronize()
                out[len(out)] = (pred.positions, 10 / (time.perf_counter() - start))
            diff = float(np.nanmax(np.abs(out[0][0] - out[1][0])))
            worst = max(worst, diff)
            print(
                f"{name} skin={skin}: max |{devices[0]} - {devices[1]}| {diff:.2e} m; steps/s "
                f"{out[0][1]:.1f} / {out[1][1]:.1f}"
            )
    return 0 if worst <= 1e-4 else 1


if __name__ == "__main__":
    sys.exit(main(tuple(sys.argv[1:3]) if len(sys.argv) > 2 else ("cpu", "cuda")))
