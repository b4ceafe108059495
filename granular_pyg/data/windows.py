"""Windows of ground-truth trajectories: ``H + 1`` past positions and the target, every k frames.

A window at frame ``t`` with time-step multiple ``k`` holds the positions at frames
``t - H k, ..., t - k, t`` (so ``H`` velocities over steps of ``k`` frames) and the target at
``t + k``. Only particles present in all ``H + 2`` frames take part (particles that have left
through the outflow are masked out); windows without any such particle are skipped. With
``keep_leaving``, a particle present in the ``H + 1`` input frames that leaves before the target
frame takes part too, with a NaN target (left out of the loss), as a rollout keeps it in the
graph until it crosses the outflow. A window's ``props`` are its particles' rows of the
trajectory's radii, with the Scene's materials (inputs of models with ``model.radius_feature`` or
``model.material_features``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from granular_pyg.errors import InputError
from granular_pyg.io import Trajectory, read_trajectory
from granular_pyg.samples import SAMPLES_DIR
from granular_pyg.scenes import WallSet
from granular_pyg.simulator import ParticleProps

__all__ = ["Window", "WindowDataset", "load_split"]


@dataclass
class Window:
    """One training sample before graph building.

    Attributes:
        pos_seq: ``[N, H + 1, 3]`` float32 positions (m), oldest first.
        target_pos: ``[N, 3]`` float32 position one learned step later (m).
        walls: the trajectory's walls.
        time: recorded time (s) of the last position.
        outflow_z: the scene's outflow height (m) or None.
        index: ``(trajectory, frame)`` it came from.
        epoch: training epoch it was drawn for (seeds its noise).
        props: the ``N`` particles' radii and the Scene's materials (:class:`ParticleProps`).
    """

    pos_seq: torch.Tensor
    target_pos: torch.Tensor
    walls: WallSet
    time: float
    outflow_z: float | None
    index: tuple[int, int]
    epoch: int = 0
    props: ParticleProps | None = None


def load_split(root: str | Path | None, sample: str | None, split: str) -> list[Path]:
    """Trajectory files of a dataset folder's split (``manifest.json``), or of a bundled sample.

    Args:
        root: a folder made by ``python -m granular_pyg.generate`` (or None).
        sample: ``"hopper"`` or ``"drum"`` for the bundled sample when ``root`` is None.
        split: ``"train"``, ``"valid"`` or ``"test"``.
    """
    if root is None and sample is None:
        raise InputError("data: set data.root (a dataset folder) or data.sample (hopper or drum)")
    folder = Path(root) if root is not None else SAMPLES_DIR / str(sample)
    manifest = folder / "manifest.json"
    if not manifest.is_file():
        raise InputError(
            f"{manifest}: no dataset manifest; make one with "
            "`python -m granular_pyg.generate scene=... out=<folder>` or set data.sample"
        )
    try:
        splits = json.loads(manifest.read_text())["splits"]
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(
            f"{manifest}: not a readable JSON manifest ({exc}); make it again with `generate` "
            "(it resumes) or `data.combine`"
        ) from None
    except (KeyError, TypeError):
        raise InputError(
            f'{manifest}: no "splits" section; a dataset manifest lists its trajectories '
            'per split ({"splits": {"train": [...], ...}})'
        ) from None
    if not isinstance(splits, dict):
        raise InputError(f'{manifest}: "splits" must map split names to file lists')
    if split not in splits:
        raise InputError(f"{manifest}: no split {split!r}; it has {sorted(splits)}")
    return [folder / name for name in splits[split]]


class WindowDataset(Dataset):
    """All windows of a list of trajectories, held in memory.

    Args:
        trajectories: Trajectory objects or HDF5 paths.
        history: ``H`` past velocities.
        frames_per_step: time-step multiple ``k`` (saved frames per learned step).
        extra_steps: further target frames kept after the window (push-forward and unrolled
            training):
            ``future [N, extra_steps, 3]`` at ``t + 2k, ...``, NaN for a particle that has
            left by then. They do not change which particles a window holds (those present
            in its ``H + 2`` frames), so the plain windows are the same with or without them.
    """

    def __init__(
        self,
        trajectories: list[Trajectory | str | Path],
        history: int = 5,
        frames_per_step: int = 1,
        extra_steps: int = 0,
    ) -> None:
        if frames_per_step < 1 or history < 1:
            raise InputError(
                f"frames_per_step ({frames_per_step}) and history ({history}) must be >= 1"
            )
        self.trajs = [t if isinstance(t, Trajectory) else read_trajectory(t) for t in trajectories]
        if not self.trajs:
            raise InputError("trajectories: the split is empty; give at least one trajectory")
        for traj in self.trajs:
            if traj.scene is None:
                raise InputError("trajectories: a training trajectory needs its Scene (walls)")
            traj.check_even_spacing()
        self.walls = [WallSet(traj.scene) for traj in self.trajs]
        self.props = [ParticleProps.of(traj) for traj in self.trajs]
        self.history, self.frames_per_step, self.extra_steps = (
            int(history),
            int(frames_per_step),
            int(extra_steps),
        )
        span_before, span_after = (
            self.history * self.frames_per_step,
            (1 + self.extra_steps) * self.frames_per_step,
        )
        self.index: list[tuple[int, int]] = []
        for i, traj in enumerate(self.trajs):
            present = traj.present
            for t in range(span_before, traj.num_frames - span_after):
                if present[self._frames(t)[: self.history + 2]].all(axis=0).any():
                    self.index.append((i, t))
        if not self.index:
            raise InputError(
                f"no window of {self.history + 2 + self.extra_steps} frames "
                f"({self.frames_per_step} frames per step) has a particle present throughout: "
                "use longer trajectories or a smaller frames_per_step"
            )

    def _frames(self, t: int) -> np.ndarray:
        first = t - self.history * self.frames_per_step
        last = t + (1 + self.extra_steps) * self.frames_per_step
        return np.arange(first, last + 1, self.frames_per_step)

    @property
    def frame_dt(self) -> float:
        """Recorded frame spacing (s) of the first trajectory."""
        return self.trajs[0].frame_dt

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item: int | tuple[int, int]) -> Window:
        """Window ``item``, or ``(epoch, item)`` as :class:`EpochSampler` draws them."""
        epoch, item = item if isinstance(item, tuple) else (0, item)
        i, t = self.index[item]
        traj = self.trajs[i]
        frames = self._frames(t)
        h = self.history + 1
        keep = traj.present[frames[: self.history + 2]].all(axis=0)
        window = torch.from_numpy(traj.positions[frames][:, keep]).permute(1, 0, 2)
        sample = Window(
            pos_seq=window[:, :h].contiguous(),
            target_pos=window[:, h].contiguous(),
            walls=self.walls[i],
            time=float(traj.times[t]),
            outflow_z=traj.scene.outflow_z,
            index=(i, t),
            epoch=int(epoch),
            props=self.props[i][torch.from_numpy(keep)],
        )
        if self.extra_steps:
            sample.future = window[:, h + 1 :].contiguous()  # type: ignore[attr-defined]
        return sample
