"""``python -m tools.rest_stiffness <ckpt> <trajectory>`` (from the checkout's root): does a
model push a particle displaced at rest back?

The trajectory's first frame is held still (``held_still``: velocities zero, walls never moving
or removed). Two sets of 40 particles, the lowest (on the floor or lid) and a random 40 of the
middle third by height, are then held displaced by ``delta`` along z over the whole history (at
rest, displaced) and the first learned step's vertical acceleration of those particles is read.
Printed: the bed's bias (mean a_z undisplaced, m/s^2), over the bed and per tenth of it by
height (a bias the same at every height is not the lid's doing), and, per ``delta`` in +-0.1,
0.2, 0.5 mm, the change of the set's mean a_z (m/s^2). A restoring model answers with the
opposite sign, growing with ``|delta|``; a dead-beat correction within one step is ``-delta / dt^2``
(0.31 m/s^2 for 0.5 mm at dt = 40 ms).

Then the whole bed is given one vertical velocity ``v``, over its whole history (each
particle's past positions shifted by ``v (t - t_last)``) and, second, over its last step only
(the earlier frames shifted by ``-v dt``: at rest, then a sudden start), the last frame at rest;
the change of the bed's mean a_z is printed per ``v`` in +-1, 4, 10 mm/s. A bed at rest stops
such a motion: a dead-beat stop is ``-v / dt`` (+0.10 m/s^2 for -4 mm/s); a model that answers
a sinking bed with a downward acceleration turns the first step's small sink into a discharge
through the lid.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import torch

from granular_pyg.bench.trajectories import resolve_trajectory
from granular_pyg.evaluation.variants import held_still
from granular_pyg.inference import load_simulator, rollout_trajectory

DELTAS_M = (-5e-4, -2e-4, -1e-4, 1e-4, 2e-4, 5e-4)
SPEEDS_M_S = (-1e-2, -4e-3, -1e-3, 1e-3, 4e-3, 1e-2)


def _first_step_acceleration(sim, traj) -> np.ndarray:
    """``[N, 3]`` (m/s^2): the first learned step's acceleration from ``traj``'s history."""
    with torch.inference_mode():
        pos = rollout_trajectory(sim, traj, steps=1, progress=False).positions.astype(np.float64)
    return (pos[-1] - 2 * pos[-2] + pos[-3]) / float(sim.dt) ** 2


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ckpt", help="a checkpoint or pretrained:<name>")
    parser.add_argument("trajectory", help="a trajectory file or sample:hopper / sample:drum")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    sim, _ = load_simulator(args.ckpt)
    rest = held_still(resolve_trajectory(args.trajectory), 0.5)
    height = rest.positions[0][:, 2]
    order = np.argsort(height)
    third = len(order) // 3
    sets = {
        "lowest": order[:40],
        "middle": np.random.default_rng(0).choice(order[third : 2 * third], 40, replace=False),
    }
    base = _first_step_acceleration(sim, rest)
    print(f"{args.ckpt}: bias a_z {base[:, 2].mean():+.3f} m/s^2 (dt {float(sim.dt):g} s)")
    tenths = np.array_split(order, 10)
    print(
        "  bias by height tenth, bottom to top: "
        + " ".join(f"{base[t, 2].mean():+.3f}" for t in tenths)
    )
    for name, idx in sets.items():
        changes = []
        for delta in DELTAS_M:
            pos = rest.positions.copy()
            pos[:, idx, 2] += delta
            acc = _first_step_acceleration(sim, dataclasses.replace(rest, positions=pos))
            change = acc[idx, 2].mean() - base[idx, 2].mean()
            changes.append(f"{1e3 * delta:+.1f} mm: {change:+.3f}")
        print(f"  {name} 40 held displaced, change of a_z (m/s^2): " + ", ".join(changes))
    steps_per_frame = round(float(sim.dt) / float(rest.times[1] - rest.times[0]))
    t_last = rest.times[sim.history * steps_per_frame]  # the first step's last history frame
    before_last = rest.times < t_last - 1e-9
    for label, shift in (
        ("whole bed moving along z", lambda v: v * (rest.times - t_last)),
        ("whole bed's last step along z", lambda v: np.where(before_last, -v * float(sim.dt), 0)),
    ):
        changes = []
        for speed in SPEEDS_M_S:
            pos = rest.positions.copy()
            pos[:, :, 2] += shift(speed)[:, None]
            acc = _first_step_acceleration(sim, dataclasses.replace(rest, positions=pos))
            change = acc[:, 2].mean() - base[:, 2].mean()
            changes.append(f"{1e3 * speed:+.0f} mm/s: {change:+.3f}")
        print(f"  {label}, change of mean a_z (m/s^2): " + ", ".join(changes))


if __name__ == "__main__":
    main()
