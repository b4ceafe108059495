"""TrajectoryDataModule: windows of the HDF5 trajectories, as batches of graphs."""

from __future__ import annotations

import zlib
from pathlib import Path

import lightning as L
import torch
from torch.utils.data import DataLoader, Sampler
from torch_geometric.data import Batch, Data

from granular_pyg.data import NormalizationStats, Window, WindowDataset, compute_statistics
from granular_pyg.data.windows import load_split
from granular_pyg.errors import InputError, finite_number, whole_number
from granular_pyg.geometry import random_horizontal_frame
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.sleep import at_rest
from granular_pyg.training.objectives import Objective
from granular_pyg.training.reach_mask import within_reach_of_events
from granular_pyg.transforms import AddRandomWalkNoise

__all__ = ["EpochSampler", "ResumableLoader", "TrajectoryDataModule"]


class EpochSampler(Sampler[tuple[int, int]]):
    """A permutation (or random subset) of the windows that depends on ``(seed, epoch)`` only,
    so a resumed run sees the same order. Yields ``(epoch, window)`` pairs so that each
    window's noise can depend on the epoch too. Lightning calls :meth:`set_epoch`; under DDP it
    wraps this sampler and gives each rank its share."""

    def __init__(
        self,
        size: int,
        num_samples: int | None,
        seed: int,
        shuffle: bool,
    ) -> None:
        self.size, self.seed, self.shuffle = size, seed, shuffle
        self.num_samples = size if num_samples is None else int(num_samples)
        self.epoch = 0
        # (epoch, samples) a run resumed mid-epoch leaves out of that epoch's next pass
        self.skip_next: tuple[int, int] | None = None

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.num_samples

    def __iter__(self):
        if not self.shuffle:
            order = list(range(min(self.size, self.num_samples)))
        else:
            g = torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch)
            reps = -(-self.num_samples // self.size)
            perms = torch.cat([torch.randperm(self.size, generator=g) for _ in range(reps)])
            order = perms[: self.num_samples].tolist()
        skip = 0
        if self.skip_next is not None and self.skip_next[0] == self.epoch:
            skip = self.skip_next[1]
        self.skip_next = None
        return iter([(self.epoch, i) for i in order[skip:]])


class ResumableLoader(DataLoader):
    """A DataLoader that a run killed mid-epoch resumes where it stopped (Lightning saves its
    :meth:`state_dict` with each checkpoint and calls :meth:`load_state_dict` on resume).

    Its state is the epoch and the number of its batches the training loop had finished, read
    through ``progress`` (Lightning's own counts, so batches the loop fetched ahead of time do
    not count). After :meth:`load_state_dict` the next pass of that epoch leaves them out of its
    :class:`EpochSampler` (single process; under DDP Lightning replaces the sampler). A
    checkpoint taken at an epoch's last batch resumes with the next epoch whole: Lightning then
    starts the next epoch, whose number no longer matches.
    """

    def __init__(self, *args, progress=None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.progress = progress

    def state_dict(self) -> dict:
        epoch, done = self.progress() if self.progress else (0, 0)
        return {"epoch": int(epoch), "batches_done": int(done)}

    def load_state_dict(self, state: dict) -> None:
        if isinstance(self.sampler, EpochSampler) and "epoch" in state:
            done = int(state.get("batches_done", 0)) * int(self.batch_size)
            self.sampler.skip_next = (int(state["epoch"]), done)


class _Collate:
    """Windows -> one Batch of graphs (runs in the loader's worker processes).

    Noise (training only; resampled where it would cross a wall, as BGNN does) and features come
    from the simulator's own ``build_graph`` and ``target_acceleration``, the one place features
    are built. The noise of a window is seeded by ``(seed, epoch, window)``, so it does not
    depend on workers or on resuming. With ``augment`` each window is seen in a random frame
    turned about gravity and mirrored half the time (``window.frame``, seeded the same way):
    features and target in that frame, the graph unchanged. A model with ``canonical_frame``
    sees each window in its scene's own frame instead, as its rollouts do.
    """

    def __init__(
        self,
        sim: LearnedSimulator,
        noise_std: float,
        seed: int,
        correct_positions: bool = False,
        augment: bool = False,
        offset_std: float = 0.0,
        drift_std: float = 0.0,
        mask_beyond_reach: bool = False,
        rest_weight: float = 1.0,
    ):
        self.sim, self.noise_std, self.seed = sim, noise_std, seed
        self.rest_weight = rest_weight
        self.offset_std, self.drift_std = offset_std, drift_std
        self.mask_beyond_reach = mask_beyond_reach
        self.correct_positions = correct_positions
        self.augment = augment

    def __call__(self, windows: list[Window]) -> Batch:
        graphs = []
        dt = float(self.sim.dt)
        noised = self.noise_std > 0 or self.offset_std > 0 or self.drift_std > 0
        for w in windows:
            pos_seq, target = w.pos_seq, w.target_pos
            rest = at_rest(pos_seq, dt) if self.rest_weight != 1.0 else None
            if noised:
                key = zlib.crc32(f"{self.seed}/{w.epoch}/{w.index}".encode())
                noise = AddRandomWalkNoise(
                    self.noise_std,
                    resample_at_walls=True,
                    generator=torch.Generator().manual_seed(key),
                    correct_positions=self.correct_positions,
                    offset_std=self.offset_std,
                    drift_std=self.drift_std,
                )
                data = noise(Data(pos_seq=pos_seq, target_pos=target, walls=w.walls, time=w.time))
                pos_seq, target = data.pos_seq, data.target_pos
            w.frame = self.sim.scene_frame(w.walls, pos_seq[:, -1])  # None: the world's
            if self.augment:
                key = zlib.crc32(f"frame/{self.seed}/{w.epoch}/{w.index}".encode())
                w.frame = random_horizontal_frame(torch.Generator().manual_seed(key))
            with torch.no_grad():
                graph = self.sim.build_graph(pos_seq, w.walls, w.time, props=w.props, frame=w.frame)
                graph.y = self.sim.target_acceleration(pos_seq, target, w.frame)
            if self.mask_beyond_reach:
                reached = within_reach_of_events(
                    w.walls, pos_seq[:, -1], w.time, dt, self.sim.reach
                )
                graph.y[~reached] = float("nan")
            if self.rest_weight != 1.0:
                graph.weight = torch.where(rest, self.rest_weight, 1.0).to(graph.y.dtype)
            graphs.append(graph)
        batch = Batch.from_data_list(graphs)
        batch.windows = windows  # raw windows, for objectives that run the model on
        batch.mask_beyond_reach = self.mask_beyond_reach  # they mask their own steps alike
        return batch


class TrajectoryDataModule(L.LightningDataModule):
    """Windows of trajectories (H past velocities + target every ``frames_per_step`` frames),
    split by trajectory, with normalisation statistics from the training split.

    Args:
        root: dataset folder with ``manifest.json`` (from ``python -m granular_pyg.generate``);
            None to use the bundled ``sample``.
        sample: ``"hopper"`` or ``"drum"`` (used when ``root`` is None).
        history: past velocities ``H`` (must match the model).
        frames_per_step: time-step multiple ``k``: one learned step spans ``k`` saved frames.
        batch_size: windows per batch.
        num_workers: loader worker processes (0: build graphs in the main process).
        noise_std: random-walk noise on the training inputs (m per step), resampled where it
            would cross a wall; the statistics' stds are inflated by it.
        noise_target: ``"velocity"`` (GNS: the target keeps the last position's noise, the
            model learns to correct velocities) or ``"position"`` (the clean target: the model
            also learns to undo position noise, i.e. to push pressed particles apart).
        offset_noise_std: a displacement (m, std per axis) held over a window's whole history,
            velocities clean, target clean: the model learns to push a particle displaced at
            rest back (see :class:`~granular_pyg.transforms.AddRandomWalkNoise`).
        drift_noise_std: a random walk shared by a window's particles (last velocity std, m
            per learned step), the last position and the target clean: the model learns to
            stop a bed's coherent motion that the truth does not have.
        mask_beyond_reach: leave out of the training loss the particles that a wall event (a
            wall removed, a motion started, stopped or reversed) within the step or the
            history's last step cannot reach through the model's message passing
            (``sim.reach``); validation keeps them.
        rest_weight: the one-step loss weighs a particle whose clean history is at rest
            (slower than 1 mm/s at every step: :func:`at_rest`) this many times more. A bed
            at rest needs its acceleration to about 0.01 m/s^2, in a loss whose scale is set
            by the flow's (m/s^2).
        train_samples_per_epoch: windows drawn per epoch (None: all of them once).
        val_samples: validation windows per epoch (None: all).
        trajectories: optional explicit lists ``{"train": [...], "valid": [...]}`` of files.
        seed: seed of the window order, the noise and the frames.
        augment: see every training window in a random frame turned about gravity (z) and
            mirrored half the time (positions, velocities, walls and their motion, target), so
            that a model learns that only the vertical is fixed; validation windows are not
            turned.

    The training windows also hold the future frames that the objective given to
    :meth:`attach` needs (``Objective.future_frames``).
    """

    def __init__(
        self,
        root: str | None = None,
        sample: str | None = "hopper",
        history: int = 5,
        frames_per_step: int = 1,
        batch_size: int = 2,
        num_workers: int = 0,
        noise_std: float = 0.0,
        noise_target: str = "velocity",
        offset_noise_std: float = 0.0,
        drift_noise_std: float = 0.0,
        mask_beyond_reach: bool = False,
        rest_weight: float = 1.0,
        train_samples_per_epoch: int | None = None,
        val_samples: int | None = None,
        trajectories: dict | None = None,
        seed: int = 0,
        augment: bool = True,
    ) -> None:
        super().__init__()
        if root is None and sample is None:
            raise InputError("data: set data.root (a dataset folder) or data.sample")
        self.root, self.sample = root, sample
        self.history = whole_number("data.history", history, minimum=1)
        self.frames_per_step = whole_number("data.frames_per_step", frames_per_step, minimum=1)
        self.batch_size = whole_number("data.batch_size (windows per batch)", batch_size, 1)
        self.num_workers = whole_number("data.num_workers", num_workers)
        self.noise_std = finite_number("data.noise_std", noise_std, minimum=0.0)
        self.offset_noise_std = finite_number(
            "data.offset_noise_std", offset_noise_std, minimum=0.0
        )
        self.drift_noise_std = finite_number("data.drift_noise_std", drift_noise_std, minimum=0.0)
        if not isinstance(mask_beyond_reach, bool):
            raise InputError(
                f"data.mask_beyond_reach: expected true or false, got {mask_beyond_reach!r}"
            )
        self.mask_beyond_reach = mask_beyond_reach
        self.rest_weight = finite_number("data.rest_weight", rest_weight, minimum=0.0)
        if noise_target not in ("velocity", "position"):
            raise InputError(
                f"noise_target: expected 'velocity' or 'position', got {noise_target!r}"
            )
        self.correct_positions = noise_target == "position"
        self.train_samples, self.val_samples = train_samples_per_epoch, val_samples
        self.extra_steps = 0
        self.trajectories = trajectories
        self.seed = int(seed)
        if not isinstance(augment, bool):
            raise InputError(f"data.augment: expected true or false, got {augment!r}")
        self.augment = augment
        self.sim: LearnedSimulator | None = None
        self.stats: NormalizationStats | None = None

    def _files(self, split: str) -> list[Path]:
        if self.trajectories and split in self.trajectories:
            return [Path(p) for p in self.trajectories[split]]
        return load_split(self.root, self.sample, split)

    def setup(self, stage: str | None = None) -> None:
        if getattr(self, "train_set", None) is not None:
            return
        self.train_set = WindowDataset(
            self._files("train"), self.history, self.frames_per_step, extra_steps=self.extra_steps
        )
        self.val_set = WindowDataset(self._files("valid"), self.history, self.frames_per_step)
        self.stats = compute_statistics(self.train_set.trajs, self.frames_per_step, self.noise_std)

    @property
    def dt(self) -> float:
        """The learned step (s): the training frames' spacing times ``frames_per_step``; the
        one place it is resolved (:meth:`prepare` first)."""
        return self.frames_per_step * self.train_set.frame_dt

    def prepare(self, objective: Objective | None = None) -> None:
        """Read the windows, with the future frames ``objective`` needs: the learned step
        (:attr:`dt`) and the statistics are known from here on, before the model is built."""
        needed = objective.future_frames if objective is not None else 0
        if getattr(self, "train_set", None) is not None and needed > self.extra_steps:
            self.train_set = None  # set up again with the future frames
        self.extra_steps = max(self.extra_steps, needed)
        self.setup()

    def attach(self, sim: LearnedSimulator, objective: Objective | None = None) -> None:
        """Give ``sim`` this data's statistics and learned step, and build graphs with it; the
        training windows hold the future frames ``objective`` needs."""
        self.prepare(objective)
        if sim.history != self.history:
            raise InputError(f"model.history ({sim.history}) != data.history ({self.history})")
        if self.augment and sim.canonical_frame:
            raise InputError(
                "data.augment: a model with model.canonical_frame sees every scene in the "
                "scene's own frame, turned copies alike; set data.augment=false"
            )
        sim.set_normalization(
            self.stats.vel_mean, self.stats.vel_std, self.stats.acc_mean, self.stats.acc_std
        )
        sim.dt.fill_(self.dt)
        self.sim = sim

    def _loader(
        self,
        dataset,
        num_samples,
        shuffle: bool,
        noise: float,
        augment: bool = False,
        offset: float = 0.0,
        drift: float = 0.0,
        mask: bool = False,
        rest_weight: float = 1.0,
        **kwargs,
    ) -> DataLoader:
        if self.sim is None:
            raise InputError("TrajectoryDataModule.attach(simulator) must come before loading")
        collate = _Collate(
            self.sim,
            noise,
            self.seed,
            self.correct_positions,
            augment,
            offset,
            drift,
            mask,
            rest_weight,
        )
        sampler = EpochSampler(len(dataset), num_samples, self.seed, shuffle)
        return (ResumableLoader if kwargs else DataLoader)(
            dataset,
            batch_size=self.batch_size,
            sampler=sampler,
            collate_fn=collate,
            num_workers=self.num_workers,
            persistent_workers=False,
            **kwargs,
        )

    def _batches_done(self) -> tuple[int, int]:
        """(epoch, training batches of it the loop has finished), Lightning's counts."""
        done = self.trainer.fit_loop.epoch_loop.batch_progress.current.processed
        return self.trainer.current_epoch, done

    def train_dataloader(self) -> DataLoader:
        return self._loader(
            self.train_set,
            self.train_samples,
            True,
            self.noise_std,
            self.augment,
            self.offset_noise_std,
            self.drift_noise_std,
            self.mask_beyond_reach,
            self.rest_weight,
            progress=self._batches_done if self.trainer is not None else None,
        )

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.val_set, self.val_samples, False, 0.0)
