"""``python -m tools.gns_side_by_side`` (from the checkout's root; not part of the installed
package, as it needs a gns checkout): training and inference steps of this
simulator and of geoelements/gns (a PyTorch + PyG GNS whose walls are kinematic particles), side
by side on the same bundled-hopper windows at matched size::

    python -m tools.gns_side_by_side --gns /tmp/gns [--steps 5] [--threads 2] \\
        [--precision 32|bf16] [--out outputs/gns_side_by_side]

``--gns`` is a checkout of https://github.com/geoelements/gns (the folder holding ``gns/``); its
code is imported from there (``sys.path``), never copied here. It needs, besides torch and
torch_geometric, ``torch_cluster``, ``absl-py`` and ``tqdm`` (imported by its ``train.py``); the
project's venv has all three. ``torch_scatter`` and ``torch_sparse``, listed in its
requirements, are not needed with PyG >= 2.3 (message passing falls back to
``torch.scatter_reduce``). gns's ``torch_geometric.nn.radius_graph`` needs ``pyg-lib`` under
PyG >= 2.8, which has no wheel for the venv's torch (nor one on PyPI): without it, the gns child
points gns's ``radius_graph`` at ``torch_cluster.radius_graph``, the function PyG called before
(same arguments, same edges).

**Conversion** (into ``--out/data``, gns's format: ``docs/gns_data.md`` of gns).
gns needs a fixed particle set without NaN, so each bundled hopper trajectory keeps only the
frames from the first one at which every removed wall is gone (the lid, removed at 0.02 s) up to
the last one before the first particle leaves through the outflow plane; every trajectory is cut
to the shortest such range, ``T`` frames (22 windows each for the sample). The particle set is
then the whole sample's (no particle is dropped), and the lid, absent throughout, is dropped.
Each remaining wall's triangles are sampled at about one particle diameter (``--wall-spacing``):
a dense barycentric grid on every triangle is thinned greedily so that no two kept points are
closer than the spacing (Poisson-disk), so every point lies on the mesh and moves with the wall
(its barycentric coordinates are applied to the wall's posed vertices at each frame; the
hopper's walls are static). These are gns's kinematic particles, ``particle_type`` 3
(``KINEMATIC_PARTICLE_ID`` of gns's ``train.py``), after the grains, ``particle_type`` 6 (gns's
"sand"). Written: ``train.npz``, ``valid.npz`` and ``test.npz`` (the sample's splits), each
``{"simulation_<i>": (positions [T, N + K, 3] float32 m, particle_type [N + K] int64)}``, and
``metadata.json``: ``bounds`` (the scenes' domain boxes, m), ``sequence_length`` ``T``,
``default_connectivity_radius`` 0.0075 m, ``dim`` 3, ``dt`` (s per frame), and ``vel_mean``,
``vel_std``, ``acc_mean``, ``acc_std`` [3]: first and second frame differences of the grains'
positions (m per frame, m per frame^2; gns's Euler step has dt = 1), pooled over every frame and
grain of the training split (population std; kinematic particles left out: their zero motion is
not what the model predicts). The same cut trajectories, in this project's HDF5 format with
their Scene, go to ``--out/data_granular_pyg`` (with a ``manifest.json``) so that our model
trains on exactly the same windows.

**Timing.** Each framework runs in its own child process (multiprocessing spawn, so that
``ru_maxrss`` is its own peak resident memory), with ``--threads`` torch threads. The two
children alternate operation by operation (one gns step, one of ours, ...), each waiting while
the other runs, so that load from other jobs on the machine falls on both alike: first
``--warmup`` + ``--steps`` training steps, then as many inference steps; the first ``--warmup``
of each are not timed, and the report gives medians.

* gns: its ``train._get_simulator`` (latent 128, 10 message-passing steps, 2-layer MLPs of 128)
  with the converted metadata; a training step is one batch of one window from its own
  ``SamplesDataset`` loader (shuffled), its random-walk noise (``noise_utils``, masked off the
  kinematic particles), ``predict_accelerations``, its ``acceleration_loss``, backward and an
  Adam step (lr 1e-4). The noise's std is ours (``data.noise_std``), so that both see the same
  graphs. An inference step is ``predict_positions`` (radius graph, features, forward, Euler
  integration) of one window (the middle one of the first training trajectory), under
  ``torch.inference_mode``.
* ours: ``compose("train", ["model.latent=128", "model/processor=gns", "model.radius=0.0075",
  "data.batch_size=1", "data.root=<the cut trajectories>"])`` (``conf/model/processor/gns.yaml``:
  10 interaction-network steps); a training step is timed as ``bench.training`` does (its
  ``_throughput``: the real Lightning pipeline, windows -> graphs in the loader's collate ->
  forward -> backward -> Adam, from one optimiser step's end to the next), with its clock
  replaced in the child by one that records each step and hands the turn over. An inference
  step is ``sim(sim.build_graph(...))`` of the same window under ``torch.inference_mode``.

Edges are those of the inference window's graph: gns's radius graph over grains and kinematic
particles (self-loops included, at most 128 neighbours); ours, the radius graph over grains plus
the particle-wall edges of its wall nodes. Writes ``--out/report.md`` (the table and the
command), ``--out/results.json`` (every per-step time) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import queue
import resource
import statistics
import sys
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from granular_pyg.cli import reports_errors
from granular_pyg.errors import InputError, whole_number
from granular_pyg.io import Trajectory, atomic_write, read_trajectory, write_trajectory
from granular_pyg.io.markdown import command_header, markdown_table
from granular_pyg.samples import sample_files

__all__ = [
    "GNS_GRAIN_TYPE",
    "GNS_KINEMATIC_TYPE",
    "Conversion",
    "convert",
    "gns_statistics",
    "kept_frames",
    "sample_triangles",
    "side_by_side",
]

#: gns's ``KINEMATIC_PARTICLE_ID`` (``gns/train.py``): walls as particles that follow their
#: prescribed positions and carry no loss.
GNS_KINEMATIC_TYPE = 3
#: The grains' type (gns's datasets call sand 6); any type below its 9 would do.
GNS_GRAIN_TYPE = 6
#: Input frames of a gns window (``INPUT_SEQUENCE_LENGTH``: 5 velocities), plus the target.
GNS_WINDOW_FRAMES = 6 + 1
#: Matched model size.
CONNECTIVITY_RADIUS = 0.0075  # m
OUR_OVERRIDES = ("model.latent=128", "model.radius=0.0075", "data.batch_size=1")
SPLITS = ("train", "valid", "test")
#: Seconds a child waits for its turn before giving up (the other one may have hung).
TURN_TIMEOUT = 1800.0


# -- conversion --------------------------------------------------------------------------------


def kept_frames(traj: Trajectory) -> tuple[int, int]:
    """``(start, stop)``: the frames ``[start, stop)`` gns can use, from the first frame at
    which every wall with a removal time is gone to the last one with every particle present.

    Raises:
        InputError: the trajectory has no Scene.
    """
    if traj.scene is None:
        raise InputError("the trajectory has no Scene: its walls are needed")
    start = 0
    for wall in traj.scene.walls:
        if wall.removal_time is not None:
            gone = [i for i, t in enumerate(traj.times) if not wall.present(float(t))]
            start = max(start, gone[0] if gone else traj.num_frames)
    missing = np.flatnonzero(~traj.present[start:].all(axis=1))
    return start, start + int(missing[0] if missing.size else traj.num_frames - start)


def sample_triangles(triangles: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on a triangle mesh, no two closer than ``spacing`` and none farther than about
    ``spacing`` from the next (greedy Poisson-disk thinning of a dense barycentric grid).

    Args:
        triangles: ``[F, 3, 3]`` vertex positions per triangle (m).
        spacing: smallest distance between two points (m).

    Returns:
        ``tri [K]`` int64, the triangle of each point, and ``bary [K, 3]`` float64, its
        barycentric coordinates there (``point = bary @ triangles[tri]``), in the grid's order.
    """
    from scipy.spatial import cKDTree

    fine = spacing / 4.0
    tris, barys = [], []
    for f, tri in enumerate(np.asarray(triangles, np.float64)):
        longest = max(np.linalg.norm(tri[a] - tri[b]) for a, b in ((0, 1), (1, 2), (2, 0)))
        n = max(1, int(np.ceil(longest / fine)))
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = (i + j) <= n
        i, j = i[keep] / n, j[keep] / n
        barys.append(np.stack([1.0 - i - j, i, j], axis=1))
        tris.append(np.full(len(i), f, np.int64))
    tri_idx, bary = np.concatenate(tris), np.concatenate(barys)
    points = np.einsum("kj,kjd->kd", bary, np.asarray(triangles, np.float64)[tri_idx])
    tree = cKDTree(points)
    covered = np.zeros(len(points), bool)
    kept = []
    for k in range(len(points)):
        if covered[k]:
            continue
        kept.append(k)
        covered[tree.query_ball_point(points[k], r=spacing * (1.0 - 1e-9))] = True
    kept = np.asarray(kept, np.int64)
    return tri_idx[kept], bary[kept]


@dataclass
class Conversion:
    """What :func:`convert` wrote.

    Attributes:
        gns_dir: folder of ``train.npz``, ``valid.npz``, ``test.npz`` and ``metadata.json``.
        ours_dir: folder of the cut HDF5 trajectories and their ``manifest.json``.
        frames: ``T``, frames per converted trajectory.
        first_frames: each trajectory's first kept frame in the original, by file name.
        particles: grains per trajectory, by file name.
        wall_particles: kinematic particles per trajectory, by file name.
        wall_spacing: the wall sampling's spacing (m).
        window: ``(trajectory, frame)``: the inference window, the first training trajectory
            and its last input frame (in the cut trajectory).
    """

    gns_dir: str
    ours_dir: str
    frames: int
    first_frames: dict[str, int]
    particles: dict[str, int]
    wall_particles: dict[str, int]
    wall_spacing: float
    window: tuple[int, int]


def _wall_particles(traj: Trajectory, frames: np.ndarray, spacing: float) -> np.ndarray:
    """``[T, K, 3]`` float32 (m): the kinematic particles of the walls present in every frame
    of ``frames``, posed at each frame's time."""
    parts = []
    for wall in traj.scene.walls:
        if not all(wall.present(float(traj.times[f])) for f in frames):
            continue  # removed before the kept frames (kept_frames starts after every removal)
        tri, bary = sample_triangles(wall.triangles, spacing)
        posed = [wall.vertices_at(float(traj.times[f]))[wall.faces[tri]] for f in frames]
        parts.append(np.stack([np.einsum("kj,kjd->kd", bary, v) for v in posed]))
    return np.concatenate(parts, axis=1).astype(np.float32)


def gns_statistics(trajectories: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, list[float]]:
    """gns's normalisation statistics of the non-kinematic particles.

    Args:
        trajectories: ``(positions [T, N, 3] (m), particle_type [N])`` pairs.

    Returns:
        ``vel_mean``, ``vel_std`` (m per frame), ``acc_mean``, ``acc_std`` (m per frame^2):
        per axis, over every frame difference of every such particle of every trajectory
        (population std, float64).
    """
    vel, acc = [], []
    for positions, types in trajectories:
        grains = np.asarray(positions, np.float64)[:, np.asarray(types) != GNS_KINEMATIC_TYPE]
        v = np.diff(grains, axis=0)
        vel.append(v.reshape(-1, 3))
        acc.append(np.diff(v, axis=0).reshape(-1, 3))
    vel, acc = np.concatenate(vel), np.concatenate(acc)
    return {
        "vel_mean": vel.mean(axis=0).tolist(),
        "vel_std": vel.std(axis=0).tolist(),
        "acc_mean": acc.mean(axis=0).tolist(),
        "acc_std": acc.std(axis=0).tolist(),
    }


def _write_npz(path: Path, trajectories: list[tuple[np.ndarray, np.ndarray]]) -> None:
    entries = {}
    for i, (positions, types) in enumerate(trajectories):
        pair = np.empty(2, dtype=object)  # gns unpacks (positions, particle_type)
        pair[0], pair[1] = positions, types
        entries[f"simulation_{i}"] = pair
    with atomic_write(path, "wb") as fh:
        np.savez_compressed(fh, **entries)


def convert(
    out: str | Path, sample: str = "hopper", wall_spacing: float | None = None
) -> Conversion:
    """Convert the bundled ``sample`` for gns (and cut it the same way for us); see the module
    docstring.

    Args:
        out: destination; ``out/data`` (gns) and ``out/data_granular_pyg`` (ours) are written.
        sample: the bundled sample's name.
        wall_spacing: kinematic particles' spacing (m); None: the largest particle diameter.

    Raises:
        InputError: a trajectory has fewer than 7 usable frames (one gns window).
    """
    out = Path(out)
    gns_dir, ours_dir = out / "data", out / "data_granular_pyg"
    splits = {split: sample_files(sample, split) for split in SPLITS}
    trajs = {p.name: read_trajectory(p) for files in splits.values() for p in files}
    ranges = {name: kept_frames(t) for name, t in trajs.items()}
    frames = min(stop - start for start, stop in ranges.values())
    if frames < GNS_WINDOW_FRAMES:
        raise InputError(
            f"{sample}: only {frames} frames with every particle present after the walls' "
            f"removals; gns needs at least {GNS_WINDOW_FRAMES}"
        )
    if wall_spacing is None:
        wall_spacing = 2.0 * float(max(t.radii.max() for t in trajs.values()))
    conversion = Conversion(
        str(gns_dir), str(ours_dir), frames, {}, {}, {}, float(wall_spacing), (0, frames // 2)
    )
    converted: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, traj in trajs.items():
        start = ranges[name][0]
        keep = np.arange(start, start + frames)
        walls = _wall_particles(traj, keep, wall_spacing)
        grains = traj.positions[keep]
        positions = np.concatenate([grains, walls], axis=1)
        types = np.concatenate(
            [
                np.full(grains.shape[1], GNS_GRAIN_TYPE, np.int64),
                np.full(walls.shape[1], GNS_KINEMATIC_TYPE, np.int64),
            ]
        )
        converted[name] = (positions, types)
        conversion.first_frames[name] = int(start)
        conversion.particles[name] = int(grains.shape[1])
        conversion.wall_particles[name] = int(walls.shape[1])
        cut = Trajectory(
            traj.positions[keep],
            traj.velocities[keep],
            traj.radii,
            traj.ids,
            traj.times[keep],
            traj.scene,
            traj.metadata | {"gns_side_by_side": {"frames": [int(start), int(start + frames)]}},
        )
        write_trajectory(cut, ours_dir / name)
    for split, files in splits.items():
        _write_npz(gns_dir / f"{split}.npz", [converted[p.name] for p in files])
    lo = np.min([t.scene.domain_lo for t in trajs.values()], axis=0)
    hi = np.max([t.scene.domain_hi for t in trajs.values()], axis=0)
    metadata = {
        "bounds": [[float(a), float(b)] for a, b in zip(lo, hi, strict=True)],
        "sequence_length": int(frames),
        "default_connectivity_radius": CONNECTIVITY_RADIUS,
        "dim": 3,
        "dt": float(trajs[splits["train"][0].name].frame_dt),
        **gns_statistics([converted[p.name] for p in splits["train"]]),
    }
    with atomic_write(gns_dir / "metadata.json", "w") as fh:
        json.dump(metadata, fh, indent=1)
    manifest = {
        "scene": sample,
        "splits": {split: [p.name for p in files] for split, files in splits.items()},
        "trajectories": [{"file": name} for name in trajs],
    }
    with atomic_write(ours_dir / "manifest.json", "w") as fh:
        json.dump(manifest, fh, indent=1)
    return conversion


# -- alternation between the two children ------------------------------------------------------


class _Turns:
    """Strict alternation of two processes (0 and 1): each runs an operation only while it
    holds the turn and hands it over after; once one has finished, the other runs freely.
    ``abort`` (set by the parent when a child fails) makes the waiting one raise."""

    def __init__(self, ctx) -> None:
        self.cond = ctx.Condition()
        self.turn = ctx.Value("i", 0, lock=False)
        self.done = ctx.Array("b", [0, 0], lock=False)
        self.abort = ctx.Event()

    def acquire(self, me: int) -> None:
        deadline = time.monotonic() + TURN_TIMEOUT
        with self.cond:
            while self.turn.value != me and not self.done[1 - me]:
                if self.abort.is_set():
                    raise RuntimeError("the other framework's child failed")
                if time.monotonic() > deadline:
                    raise TimeoutError(f"no turn after {TURN_TIMEOUT:g} s")
                self.cond.wait(1.0)

    def release(self, me: int, finished: bool = False) -> None:
        with self.cond:
            self.done[me] = int(finished or self.done[me])
            self.turn.value = 1 - me
            self.cond.notify_all()


def _timed(turns: _Turns, me: int, op, count: int) -> list[float]:
    """Seconds of ``count`` runs of ``op()``, each run in this child's turn."""
    seconds = []
    for _ in range(count):
        turns.acquire(me)
        start = time.perf_counter()
        op()
        seconds.append(time.perf_counter() - start)
        turns.release(me)
    return seconds


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


# -- the gns child -----------------------------------------------------------------------------


def _radius_graph_shim(learned_simulator) -> None:
    """gns calls ``torch_geometric.nn.radius_graph``, which PyG >= 2.8 serves from pyg-lib
    only (no wheel for this torch); without pyg-lib, point gns's name at
    ``torch_cluster.radius_graph``, the function PyG delegated to before (same arguments,
    same edges)."""
    import torch_geometric.typing

    if not torch_geometric.typing.WITH_RADIUS:
        import torch_cluster

        learned_simulator.radius_graph = torch_cluster.radius_graph


def _gns_child(
    gns: str,
    data_dir: str,
    window: tuple[int, int],
    steps: int,
    warmup: int,
    threads: int,
    noise_std: float,
    turns: _Turns,
    me: int,
) -> dict:
    import torch

    torch.set_num_threads(threads)
    sys.path.insert(0, str(Path(gns).resolve()))
    from gns import data_loader, learned_simulator, noise_utils, reading_utils
    from gns import train as gns_train

    _radius_graph_shim(learned_simulator)

    if gns_train.KINEMATIC_PARTICLE_ID != GNS_KINEMATIC_TYPE:
        raise InputError(
            f"gns's KINEMATIC_PARTICLE_ID is {gns_train.KINEMATIC_PARTICLE_ID}, the converter "
            f"writes {GNS_KINEMATIC_TYPE}: update GNS_KINEMATIC_TYPE"
        )
    torch.manual_seed(0)
    metadata = reading_utils.read_metadata(data_dir + "/", "train")
    sim = gns_train._get_simulator(metadata, noise_std, noise_std, "cpu")
    optimizer = torch.optim.Adam(sim.parameters(), lr=1e-4)
    loader = data_loader.get_data_loader_by_samples(
        path=f"{data_dir}/train.npz",
        input_length_sequence=gns_train.INPUT_SEQUENCE_LENGTH,
        batch_size=1,
    )
    batches = iter(loader)

    def train_step() -> None:
        nonlocal batches
        try:
            (position, types, count), labels = next(batches)
        except StopIteration:
            batches = iter(loader)
            (position, types, count), labels = next(batches)
        noise = noise_utils.get_random_walk_noise_for_position_sequence(
            position, noise_std_last_step=noise_std
        )
        moving = types != gns_train.KINEMATIC_PARTICLE_ID
        noise = noise * moving.view(-1, 1, 1)
        pred, target = sim.predict_accelerations(
            next_positions=labels,
            position_sequence_noise=noise,
            position_sequence=position,
            nparticles_per_example=count,
            particle_types=types,
        )
        loss = gns_train.acceleration_loss(pred, target, moving)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    positions, types = data_loader.load_npz_data(f"{data_dir}/train.npz")[window[0]]
    t = window[1]
    seq = torch.from_numpy(np.ascontiguousarray(positions[t - 5 : t + 1].transpose(1, 0, 2)))
    types = torch.from_numpy(np.asarray(types, np.int64))
    n = seq.shape[0]

    def infer_step() -> None:
        with torch.inference_mode():
            sim.predict_positions(seq, nparticles_per_example=[n], particle_types=types)

    sim.train()
    train_s = _timed(turns, me, train_step, warmup + steps)[warmup:]
    sim.eval()
    infer_s = _timed(turns, me, infer_step, warmup + steps)[warmup:]
    turns.release(me, finished=True)
    with torch.inference_mode():
        receivers, _ = sim._compute_graph_connectivity(seq[:, -1], [n], sim._connectivity_radius)
    kinematic = int((types == GNS_KINEMATIC_TYPE).sum())
    return {
        "framework": "gns",
        "particles": n - kinematic,
        "wall_nodes": kinematic,
        "edges": int(receivers.numel()),
        "parameters": sum(p.numel() for p in sim.parameters()),
        "train_s": train_s,
        "infer_s": infer_s,
        "peak_rss_mib": _peak_rss_mib(),
    }


# -- our child ---------------------------------------------------------------------------------


def _our_overrides(root: str) -> list[str]:
    return [*OUR_OVERRIDES, f"data.root={root}"]


def _ours_child(
    root: str,
    window: tuple[int, int],
    steps: int,
    warmup: int,
    threads: int,
    precision: str,
    turns: _Turns,
    me: int,
) -> dict:
    import logging

    import torch
    from hydra.utils import instantiate

    from granular_pyg.bench import training as training_suite
    from granular_pyg.config import compose
    from granular_pyg.heap import keep_freed_memory

    torch.set_num_threads(threads)
    keep_freed_memory()  # as `python -m granular_pyg.train` does (gns's process: as it comes)
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    train_s: list[float] = []

    class AlternatingClock(training_suite._StepClock):
        """The suite's clock, which also keeps each step's seconds and hands the turn over
        between steps (the wait is not timed)."""

        def __init__(self, warmup: int) -> None:
            super().__init__(warmup)
            self.resumed = time.perf_counter()

        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
            super().on_train_batch_end(trainer, pl_module, outputs, batch, batch_idx)
            if trainer.global_step > self.warmup:
                train_s.append(self.end - self.resumed)
            turns.release(me)
            turns.acquire(me)
            self.resumed = time.perf_counter()

    # The suite builds its own clock; this child (a fresh process) swaps in the alternating one.
    training_suite._StepClock = AlternatingClock
    turns.acquire(me)
    trainer_precision = "bf16-mixed" if precision == "bf16" else "32-true"
    row = training_suite._throughput("gns", steps, warmup, _our_overrides(root), trainer_precision)
    if len(train_s) != steps:
        raise RuntimeError(f"timed {len(train_s)} of {steps} training steps")

    cfg = compose("train", ["model/processor=gns", *_our_overrides(root)])
    sim = instantiate(cfg.model)
    data = instantiate(cfg.data)
    data.attach(sim)
    sim.eval()
    sim.set_network_precision(precision)
    w = data.train_set[data.train_set.index.index(window)]

    def infer_step() -> None:
        with torch.inference_mode():
            sim(sim.build_graph(w.pos_seq, w.walls, w.time))

    turns.release(me)
    infer_s = _timed(turns, me, infer_step, warmup + steps)[warmup:]
    turns.release(me, finished=True)
    with torch.inference_mode():
        graph = sim.build_graph(w.pos_seq, w.walls, w.time)
    return {
        "framework": "granular_pyg" + (", bf16" if precision == "bf16" else ""),
        "particles": int(graph.num_real),
        "wall_nodes": int(graph.is_wall.sum()),
        "edges": int(graph.edge_index.shape[1]),
        "parameters": row["parameters"],
        "train_s": train_s,
        "infer_s": infer_s,
        "peak_rss_mib": _peak_rss_mib(),
    }


def _child(which: str, args: tuple, turns: _Turns, me: int, results) -> None:
    try:
        fn = _gns_child if which == "gns" else _ours_child
        results.put((which, fn(*args, turns, me)))
    except BaseException:
        results.put((which, {"error": traceback.format_exc()}))


def _collect(procs: dict, results, turns: _Turns) -> dict[str, dict]:
    """Each child's row (or ``{"error": ...}``) by name; a child that dies without one (killed
    for memory, say) is an error too. The first error aborts the other child's wait."""
    got: dict[str, dict] = {}
    while len(got) < len(procs):
        try:
            which, row = results.get(timeout=5.0)
        except queue.Empty:
            gone = [w for w, p in procs.items() if w not in got and p.exitcode is not None]
            if not gone:
                continue
            try:  # its row may have arrived meanwhile
                which, row = results.get(timeout=2.0)
            except queue.Empty:
                which = gone[0]
                row = {"error": f"exited with code {procs[which].exitcode} and no result"}
        got[which] = row
        if "error" in row:
            turns.abort.set()
    return got


# -- the run -----------------------------------------------------------------------------------


def side_by_side(
    gns: str | Path,
    steps: int = 5,
    threads: int = 2,
    out: str | Path = "outputs/gns_side_by_side",
    warmup: int = 1,
    wall_spacing: float | None = None,
    precision: str = "32",
) -> dict:
    """Convert the hopper sample, time both frameworks alternately, write the report.
    ``precision`` is our network's (``"32"``, or ``"bf16"``: bf16-mixed training and bf16
    inference); gns runs in float32, the only precision it has.

    Returns:
        ``{"conversion": ..., "rows": [gns, ours]}``, each row with ``particles``,
        ``wall_nodes``, ``edges``, ``parameters``, ``train_s`` and ``infer_s`` (per-step
        seconds) and ``peak_rss_mib``.

    Raises:
        InputError: ``gns`` is not a gns checkout.
        RuntimeError: a child failed (its traceback in the message).
    """
    gns = Path(gns)
    if not (gns / "gns" / "learned_simulator.py").is_file():
        raise InputError(
            f"--gns {gns}: no gns/learned_simulator.py there; pass a checkout of "
            "https://github.com/geoelements/gns (the folder that holds gns/)"
        )
    from granular_pyg.config import compose

    out = Path(out)
    conversion = convert(out, "hopper", wall_spacing)
    noise_std = float(compose("train", list(OUR_OVERRIDES)).data.noise_std)
    ctx = mp.get_context("spawn")
    turns, results = _Turns(ctx), ctx.Queue()
    jobs = {
        "gns": (str(gns), conversion.gns_dir, conversion.window, steps, warmup, threads, noise_std),
        "ours": (conversion.ours_dir, conversion.window, steps, warmup, threads, precision),
    }
    procs = [
        ctx.Process(target=_child, args=(which, job, turns, me, results))
        for me, (which, job) in enumerate(jobs.items())
    ]
    for p in procs:
        p.start()
    try:
        got = _collect(dict(zip(jobs, procs, strict=True)), results, turns)
    finally:
        for p in procs:
            p.join(timeout=60)
            if p.is_alive():
                p.terminate()
    errors = [f"{which}:\n{row['error']}" for which, row in got.items() if "error" in row]
    if errors:
        raise RuntimeError("a timing child failed:\n" + "\n".join(errors))
    rows = [got["gns"], got["ours"]]
    result = {
        "conversion": asdict(conversion),
        "steps": steps,
        "warmup": warmup,
        "threads": threads,
        "precision": precision,
        "noise_std": noise_std,
        "rows": rows,
    }
    _write_report(out, result)
    return result


def _table(rows: list[dict]) -> str:
    gns, ours = rows
    cells = []
    for r in rows:
        cells.append(
            [
                r["framework"],
                r["particles"],
                r["wall_nodes"],
                r["edges"],
                statistics.median(r["train_s"]),
                statistics.median(r["infer_s"]),
                r["peak_rss_mib"],
            ]
        )
    ratio = [
        "ratio ours/gns",
        ours["particles"] / gns["particles"],
        ours["wall_nodes"] / gns["wall_nodes"],
        ours["edges"] / gns["edges"],
        statistics.median(ours["train_s"]) / statistics.median(gns["train_s"]),
        statistics.median(ours["infer_s"]) / statistics.median(gns["infer_s"]),
        ours["peak_rss_mib"] / gns["peak_rss_mib"],
    ]
    columns = [
        "framework",
        "particles",
        "wall nodes / kinematic particles",
        "edges",
        "s per training step",
        "s per inference step",
        "peak RSS MiB",
    ]
    return markdown_table(columns, [*cells, ratio], "lrrrrrr")


def _data_table(conv: dict) -> str:
    rows = [
        [name, conv["first_frames"][name], conv["particles"][name], conv["wall_particles"][name]]
        for name in conv["particles"]
    ]
    columns = ["trajectory", "first kept frame", "grains", "kinematic particles"]
    return markdown_table(columns, rows, "lrrr")


def _write_report(out: Path, result: dict) -> None:
    conv, rows = result["conversion"], result["rows"]
    per_step = "\n".join(
        f"- {r['framework']}: training {', '.join(f'{s:.3g}' for s in r['train_s'])} s; "
        f"inference {', '.join(f'{s:.3g}' for s in r['infer_s'])} s; "
        f"{r['parameters']:,} parameters"
        for r in rows
    )
    bf16 = result.get("precision") == "bf16"
    ours_precision = "bf16 (bf16-mixed training)" if bf16 else "float32"
    text = f"""# Side by side with geoelements/gns

{command_header("tools.gns_side_by_side")}

{_table(rows)}

Medians over {result["steps"]} step(s) after {result["warmup"]} warm-up step(s), one gns step
alternating with one of ours; {result["threads"]} torch threads each; our network in
{ours_precision}, gns's in float32; each framework in its own spawned process (peak RSS:
its `ru_maxrss` over training and inference). Batch 1, latent 128, 10 message-passing steps,
R = {CONNECTIVITY_RADIUS * 1e3:g} mm, training noise std {result["noise_std"]:g} m per step
for both. Edges and wall nodes: the inference window's graph (gns: radius graph over grains and
kinematic particles, self-loops included; ours: particle pairs plus one wall node and edge per
particle-triangle pair closer than R).

Data: the bundled hopper sample cut to the frames after the lid's removal and before the first
particle leaves, {conv["frames"]} frames per trajectory; walls as kinematic particles every
{conv["wall_spacing"] * 1e3:.3g} mm. gns's data: `{conv["gns_dir"]}`; the same cut trajectories
for us: `{conv["ours_dir"]}`. Inference window: training trajectory {conv["window"][0]}, last
input frame {conv["window"][1]}.

{_data_table(conv)}

Per step (s):
{per_step}
"""
    with atomic_write(out / "report.md", "w") as fh:
        fh.write(text)
    with atomic_write(out / "results.json", "w") as fh:
        json.dump(result, fh, indent=1)


@reports_errors
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gns", required=True, type=Path, help="a geoelements/gns checkout")
    parser.add_argument("--steps", type=int, default=5, help="timed steps of each kind")
    parser.add_argument("--warmup", type=int, default=1, help="untimed steps first")
    parser.add_argument("--threads", type=int, default=2, help="torch threads per framework")
    parser.add_argument(
        "--wall-spacing",
        type=float,
        default=None,
        help="kinematic particles' spacing (m); default: a particle diameter",
    )
    parser.add_argument(
        "--precision",
        choices=["32", "bf16"],
        default="32",
        help="our network's precision (gns: float32 always)",
    )
    parser.add_argument("--out", type=Path, default=Path("outputs/gns_side_by_side"))
    args = parser.parse_args(argv)
    whole_number("--steps", args.steps, minimum=1)
    whole_number("--warmup", args.warmup, minimum=1)
    whole_number("--threads", args.threads, minimum=1)
    result = side_by_side(
        args.gns,
        args.steps,
        args.threads,
        args.out,
        args.warmup,
        args.wall_spacing,
        args.precision,
    )
    print(_table(result["rows"]))
    print(f"report: {args.out / 'report.md'}")


if __name__ == "__main__":
    main()
