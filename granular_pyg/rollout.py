"""``python -m granular_pyg.rollout ckpt=... trajectory=... steps=...``: a learned rollout.

Starts from the trajectory's first ground-truth states, moves the walls as its Scene says (the
drum rotates, the hopper's lid goes at ``t_open``), removes particles at the outflow, and writes
the prediction as a Trajectory HDF5 file (the ground truth's format).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import torch
from omegaconf import DictConfig

from granular_pyg.checkpoint import load_simulator, resolve_checkpoint
from granular_pyg.cli import command
from granular_pyg.data import load_split
from granular_pyg.errors import InputError, Interrupted, NonFiniteError, flag, whole_number
from granular_pyg.inference import rollout_trajectory, warn_outside_training
from granular_pyg.io import (
    Trajectory,
    check_output,
    export_paraview,
    read_trajectory,
    write_trajectory,
)

__all__ = ["default_trajectory", "rollout"]

DTYPES = {"float32": torch.float32, "float64": torch.float64}


def default_trajectory(config: dict, split: str = "test") -> Path:
    """The first trajectory of ``split`` of the data a training run used."""
    data = config.get("data") or {}
    if not isinstance(data, dict) or (not data.get("root") and not data.get("sample")):
        raise InputError(
            "trajectory: the checkpoint records no training data to take a default trajectory "
            "from; pass trajectory=<file.h5>"
        )
    files = load_split(data.get("root"), data.get("sample"), split)
    if not files:
        raise InputError(f"the training data has no {split!r} trajectory; pass trajectory=...")
    return files[0]


def rollout(cfg: DictConfig) -> tuple[Trajectory, Path]:
    """Run the rollout ``cfg`` describes; returns the prediction and where it was written."""
    if cfg.dtype not in DTYPES:
        raise InputError(f"dtype: expected one of {sorted(DTYPES)}, got {cfg.dtype!r}")
    for key in ("overwrite", "wall_guard", "progress", "paraview"):
        flag(key, cfg[key])
    if cfg.trajectory and Path(cfg.trajectory).is_dir():
        raise InputError(
            f"trajectory: {cfg.trajectory} is a folder; pass one trajectory file, e.g. "
            f"trajectory={Path(cfg.trajectory) / 'traj_0000.h5'}"
        )
    torch.set_num_threads(whole_number("threads", cfg.threads, minimum=1))
    out = check_output(cfg.out, [cfg.trajectory, resolve_checkpoint(cfg.ckpt)], cfg.overwrite)
    sim, config = load_simulator(cfg.ckpt)
    steps = cfg.steps
    if cfg.get("scene") and not cfg.trajectory:  # the whole job from the scene file alone
        from granular_pyg.scene_start import start_from_scene_config

        truth, steps = start_from_scene_config(cfg.scene, sim, cfg.get("seed", 0), cfg.steps)
        source = Path(f"scene_{cfg.scene.name}")
    else:
        source = Path(cfg.trajectory) if cfg.trajectory else default_trajectory(config)
        out = check_output(out, [source], cfg.overwrite)
        truth = read_trajectory(source)
        warn_outside_training(config, truth, str(source))
    try:
        pred = rollout_trajectory(
            sim,
            truth,
            steps,
            cfg.start_frame,
            progress=cfg.progress,
            dtype=DTYPES[cfg.dtype],
            skin=cfg.skin,
            wall_guard=cfg.wall_guard,
            stop_when_empty=True,
            precision=str(cfg.get("precision", "32")),
            name=f"trajectory {source}",
        )
    except KeyboardInterrupt as exc:
        raise _interrupted(exc, out, cfg, source) from None
    except NonFiniteError as exc:
        partial = out.with_suffix(".partial.h5")
        exc.partial.metadata |= {"ckpt": str(cfg.ckpt), "truth_file": str(source)}
        _write_or_keep(exc.partial, partial)
        exc.args = (f"{exc.args[0]}\nthe {exc.step} steps before it: {partial}",)
        raise
    pred.metadata |= {"ckpt": str(cfg.ckpt), "truth_file": str(source)}
    out = _write_or_keep(pred, out)
    steps = pred.metadata["steps"]
    print(f"rollout: {steps} learned steps of {pred.metadata['dt'] * 1e3:g} ms from {source}")
    if "stopped_empty" in pred.metadata:
        print(f"stopped after step {steps}: no particle is left in the scene")
    beyond = float(pred.times[-1] - truth.times[-1])
    if beyond > 0:
        print(f"note: {beyond:.3g} s past the trajectory's end (the walls follow its Scene)")
    if cfg.wall_guard:
        fixes = pred.metadata["wall_guard_corrections"]
        print(f"wall guard: {fixes} particle-steps stopped at a wall")
    print(f"prediction: {out}")
    if cfg.paraview:
        pvd = export_paraview(out.parent / "paraview", {"prediction": pred}, progress=cfg.progress)
        print(f"ParaView: {pvd}")
    return pred, out


def _interrupted(exc: KeyboardInterrupt, out: Path, cfg: DictConfig, source: Path) -> Interrupted:
    """Ctrl-C during the rollout: the steps finished so far written to ``<out>.partial.h5``
    (metadata ``interrupted_after_step``), and the one line that says so."""
    partial = getattr(exc, "partial", None)
    if partial is None:
        return Interrupted(f"no learned step had finished; nothing was written (out={out})")
    partial.metadata |= {"ckpt": str(cfg.ckpt), "truth_file": str(source)}
    target = out.with_suffix(".partial.h5")
    try:
        write_trajectory(partial, target)
    except OSError as err:
        return Interrupted(f"the steps so far could not be kept ({err.strerror or err})")
    steps = partial.metadata["interrupted_after_step"]
    return Interrupted(f"the {steps} learned steps finished before it are kept in {target}")


def _write_or_keep(traj: Trajectory, out: Path) -> Path:
    """Write ``traj`` to ``out``; if that fails (a full disk, a folder gone), write it to a
    fallback file in the temporary folder so that the computation is not lost, and say where."""
    try:
        write_trajectory(traj, out)
        return out
    except OSError as exc:
        fallback = Path(tempfile.gettempdir()) / f"granular_pyg_{out.stem}_{os.getpid()}.h5"
        try:
            write_trajectory(traj, fallback)
        except OSError:
            raise InputError(
                f"out: writing {out} failed ({exc.strerror or exc}) and so did the fallback "
                f"{fallback}; free some space and run again"
            ) from exc
        raise InputError(
            f"out: writing {out} failed ({exc.strerror or exc}); the prediction is kept in "
            f"{fallback}"
        ) from exc


@command("rollout")
def main(cfg: DictConfig) -> None:
    rollout(cfg)


if __name__ == "__main__":
    main()
