"""Training end to end: configs, fast_dev_run of every variant and processor, multirun,
exact resume, learning, TensorBoard contents, DDP on two CPU processes."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from granular_pyg.config import CONF_DIR, compose
from granular_pyg.errors import InputError
from granular_pyg.io import read_trajectory, write_trajectory
from granular_pyg.samples import sample_files
from granular_pyg.train import train
from granular_pyg.training import SimulatorModule

REPO = Path(__file__).resolve().parents[2]
# Small and quick: a 16-wide network, one window per batch.
SMALL = ["model.latent=16", "data.batch_size=1", "trainer.enable_progress_bar=false"]


def _events(run: Path) -> EventAccumulator:
    acc = EventAccumulator(str(run / "tensorboard"), size_guidance={"scalars": 0, "images": 0})
    acc.Reload()
    return acc


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


@pytest.mark.parametrize(
    "override",
    [f"data={o}" for o in _options("data")]
    + [f"model={o}" for o in _options("model") if o != "base"]
    + [f"model/processor={o}" for o in _options("model/processor")]
    + [f"trainer={o}" for o in _options("trainer")]
    + [f"logger={o}" for o in _options("logger")]
    + [f"+experiment={o}" for o in _options("experiment")],
)
def test_every_config_group_composes(override):
    cfg = compose("train", [override])
    assert cfg.trainer._target_ == "lightning.Trainer"
    sim = instantiate(cfg.model)
    assert sim.history == cfg.data.history == 5


@pytest.mark.parametrize(
    "overrides",
    [["model=v1"], ["model=v2"], ["model=v3"]]
    + [["model=v3", f"model/processor={p}"] for p in ("gns", "bgnn", "attention", "equivariant")]
    + [["model=v3", "objective=push_forward", "objective.parts.push_forward.share=1.0"]]
    + [["model=v3", "objective=unrolled", "objective.parts.unrolled.steps=2"]]
    + [["model=v3", "objective=[unrolled,push_forward]"]],
    ids=[
        "v1",
        "v2",
        "v3",
        "gns",
        "bgnn",
        "attention",
        "equivariant",
        "push_forward",
        "unroll",
        "mixture",
    ],
)
def test_fast_dev_run_on_the_bundled_sample(tmp_path, overrides):
    metrics = train(compose("train", [*SMALL, *overrides, "trainer.fast_dev_run=true"]), tmp_path)
    assert torch.isfinite(torch.tensor(metrics["train/loss"]))
    assert torch.isfinite(torch.tensor(metrics["val/loss"]))


@pytest.mark.slow
def test_two_job_multirun_gets_a_folder_per_job(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "granular_pyg.train",
        "-m",
        "model=v1,v3",
        *SMALL,
        "trainer.fast_dev_run=true",
        f"hydra.sweep.dir={tmp_path}",
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = sorted(p.name for p in tmp_path.iterdir() if (p / ".hydra").is_dir())
    assert len(runs) == 2
    assert runs[0].startswith("0_") and "model=v1" in runs[0]
    assert runs[1].startswith("1_") and "model=v3" in runs[1]
    assert all((tmp_path / r / "checkpoints").is_dir() for r in runs)


def _steps_cfg(max_steps: int, *extra: str):
    return compose(
        "train",
        [
            *SMALL,
            "data.train_samples_per_epoch=3",
            "data.val_samples=2",
            "data.noise_std=1e-6",
            f"trainer.max_steps={max_steps}",
            "trainer.max_epochs=-1",
            "trainer.log_every_n_steps=1",
            "checkpoint.every_n_train_steps=3",
            "rollout_validation.every_n_epochs=1000",
            *extra,
        ],
    )


def _train_losses(run: Path) -> dict[int, float]:
    return {e.step: e.value for e in _events(run).Scalars("train/loss")}


@pytest.mark.slow
@pytest.mark.parametrize("objective", ["one_step", "[unrolled,push_forward]"])
def test_resume_gives_the_same_next_losses_as_an_uninterrupted_run(tmp_path, objective):
    mix = f"objective={objective}"
    train(_steps_cfg(6, mix), tmp_path / "straight")
    train(_steps_cfg(3, mix), tmp_path / "first")
    ckpt = tmp_path / "first" / "checkpoints" / "last.ckpt"
    assert ckpt.is_file()
    train(_steps_cfg(6, mix, f"ckpt_path={ckpt}"), tmp_path / "resumed")
    straight, resumed = _train_losses(tmp_path / "straight"), _train_losses(tmp_path / "resumed")
    later = [s for s in straight if s >= 3]
    assert later and all(s in resumed for s in later)
    for step in later:
        assert resumed[step] == pytest.approx(straight[step], rel=1e-6), step


def test_resume_with_a_different_model_names_the_keys(tmp_path):
    train(_steps_cfg(1, "trainer.fast_dev_run=false", "checkpoint.every_n_train_steps=1"), tmp_path)
    ckpt = tmp_path / "checkpoints" / "last.ckpt"
    with pytest.raises(InputError, match=r"model\.latent: 16 -> 32"):
        train(_steps_cfg(2, f"ckpt_path={ckpt}", "model.latent=32"), tmp_path / "again")


def test_a_checkpoint_from_before_noise_target_resumes_as_velocity(tmp_path):
    from granular_pyg.train import _check_resume

    train(_steps_cfg(1, "trainer.fast_dev_run=false", "checkpoint.every_n_train_steps=1"), tmp_path)
    ckpt = tmp_path / "checkpoints" / "last.ckpt"
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    del state["config"]["data"]["noise_target"]  # as written before the key existed
    torch.save(state, ckpt)
    _check_resume(str(ckpt), _steps_cfg(2))  # the default, velocity: the old behaviour
    with pytest.raises(InputError, match=r"data\.noise_target: 'velocity' -> 'position'"):
        _check_resume(str(ckpt), _steps_cfg(2, "data.noise_target=position"))


def test_a_checkpoint_with_the_old_keys_resumes_under_the_new_names(tmp_path):
    """Checkpoints written before ``data.frames_per_step`` and the ``objective`` group (the
    shipped ones among them) resume with today's configs; a removed option that was on is
    refused by name."""
    from granular_pyg.train import _check_resume

    train(_steps_cfg(1, "trainer.fast_dev_run=false", "checkpoint.every_n_train_steps=1"), tmp_path)
    ckpt = tmp_path / "checkpoints" / "last.ckpt"
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    data = state["config"]["data"]
    data["step"] = data.pop("frames_per_step")
    data |= {"wall_press": 0.0, "keep_leaving": False, "resample_noise_at_walls": True}
    state["config"].pop("objective")
    state["config"]["push_forward"] = {"unroll_steps": 4, "unroll_prob": 0.5, "unroll_noise": False}
    for added in ("radius_feature", "material_features", "contact_feature"):
        state["config"]["model"].pop(added)  # options that came later, off in the old model
    torch.save(state, ckpt)
    _check_resume(str(ckpt), _steps_cfg(2))
    with pytest.raises(InputError, match=r"model\.contact_feature: False -> True"):
        _check_resume(str(ckpt), _steps_cfg(2, "model.contact_feature=true"))
    with pytest.raises(InputError, match=r"data\.frames_per_step: 1 -> 2"):
        _check_resume(str(ckpt), _steps_cfg(2, "data.frames_per_step=2"))
    state["config"]["data"]["wall_press"] = 1e-3
    torch.save(state, ckpt)
    with pytest.raises(InputError, match=r"data\.wall_press=0\.001, an option removed"):
        _check_resume(str(ckpt), _steps_cfg(2))


def test_the_shipped_checkpoints_configs_migrate():
    from granular_pyg.pretrained import resolve_checkpoint
    from granular_pyg.training.saved_config import migrate_config

    # the drum was saved with the old keys (data.step, no objective); the hopper with today's
    for name, k, parts in (("hopper", 8, ["unrolled"]), ("drum", 4, [])):
        path = resolve_checkpoint(f"pretrained:{name}")
        cfg = migrate_config(torch.load(path, weights_only=False)["config"])
        assert cfg["data"]["frames_per_step"] == k and "step" not in cfg["data"]
        assert sorted(cfg["objective"]["parts"]) == parts


@pytest.mark.slow
def test_200_steps_on_one_trajectory_lower_the_validation_loss(tmp_path):
    """Learning works: 200 steps on a stretch of one bundled trajectory (frames 20-29, four
    windows while it discharges; the 600 particles of the lowest ids, to keep the test short)
    cut the loss on those windows by a clear factor. (Per-particle DEM accelerations at 2.5 ms
    frames are dominated by collisions: generalising across a whole trajectory takes far more
    than 200 steps.)"""
    traj = read_trajectory(sample_files("hopper", "train")[0])
    part = dataclasses.replace(
        traj,
        positions=traj.positions[20:30, :600],
        velocities=traj.velocities[20:30, :600],
        radii=traj.radii[:600],
        ids=traj.ids[:600],
        times=traj.times[20:30],
    )
    write_trajectory(part, tmp_path / "stretch.h5")
    one = str(tmp_path / "stretch.h5")
    cfg = compose(
        "train",
        [
            "model.latent=32",
            "trainer.enable_progress_bar=false",
            "data.batch_size=4",
            f"+data.trajectories={{train: [{one}], valid: [{one}]}}",
            "data.augment=false",  # memorising four windows: not each in a new frame
            "optim.lr=3e-3",
            "optim.decay_steps=1000",
            "trainer.max_steps=200",
            "trainer.max_epochs=-1",
            "trainer.check_val_every_n_epoch=1000",  # validate before and after only
            "data.noise_std=0",  # the same targets every epoch: a clean test of fitting
        ],
    )
    sim = instantiate(cfg.model)
    dm = instantiate(cfg.data)
    dm.attach(sim)
    module = SimulatorModule(sim, **cfg.optim)
    trainer = instantiate(cfg.trainer, logger=False, enable_checkpointing=False)
    before = trainer.validate(module, datamodule=dm, verbose=False)[0]["val/loss"]
    trainer.fit(module, datamodule=dm)
    after = trainer.validate(module, datamodule=dm, verbose=False)[0]["val/loss"]
    print(f"val/loss {before:.4g} -> {after:.4g} after 200 steps")
    assert len(dm.train_set) == 4
    assert after < before / 2.5  # measured: 0.99 -> 0.35


@pytest.mark.slow
def test_tensorboard_holds_the_scalars_and_the_rollout_figure(tmp_path):
    cfg = _steps_cfg(3, "rollout_validation.every_n_epochs=1", "rollout_validation.steps=4")
    train(cfg, tmp_path)
    tags = _events(tmp_path).Tags()
    for name in (
        "train/loss",
        "val/loss",
        "val_rollout/emd",
        "val_rollout/position_mse",
        "val_rollout/emd_step_1",
        "val_rollout/emd_step_4",
    ):
        assert name in tags["scalars"], name
    assert "val_rollout/last_frame" in tags["images"]
    image = _events(tmp_path).Images("val_rollout/last_frame")[0]
    assert image.encoded_image_string[:4] == b"\x89PNG"


DDP_SCRIPT = """
import json, os, sys
from granular_pyg.config import compose
from granular_pyg.train import train
out, overrides = sys.argv[1], sys.argv[2:]
metrics = train(compose("train", overrides), out)
rank = int(os.environ.get("LOCAL_RANK", 0))
with open(os.path.join(out, f"metrics_rank{rank}.json"), "w") as fh:
    json.dump(metrics, fh)
"""


@pytest.mark.slow
def test_ddp_on_two_cpu_processes_reduces_the_logged_loss(tmp_path):
    script = tmp_path / "ddp_train.py"
    script.write_text(DDP_SCRIPT)
    overrides = [
        *SMALL,
        "trainer=ddp",
        "trainer.accelerator=cpu",
        "trainer.devices=2",
        "trainer.max_steps=2",
        "trainer.max_epochs=-1",
        "data.train_samples_per_epoch=4",
        "data.val_samples=4",
        "rollout_validation.every_n_epochs=1000",
        "threads=1",
    ]
    proc = subprocess.run(
        [sys.executable, str(script), str(tmp_path), *overrides],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    ranks = [json.loads((tmp_path / f"metrics_rank{r}.json").read_text()) for r in (0, 1)]
    # Each rank validated different windows; the logged (reduced) values agree.
    assert ranks[0]["val/loss"] == pytest.approx(ranks[1]["val/loss"], rel=1e-6)
    assert ranks[0]["train/loss"] == pytest.approx(ranks[1]["train/loss"], rel=1e-6)


@pytest.mark.slow
def test_validation_rollout_stops_at_the_end_of_a_short_trajectory(tmp_path):
    """With k = 8 the 0.5 s validation trajectory holds 20 learned steps after the initial
    states: asking for 40 rolls out those 20 instead of failing."""
    cfg = _steps_cfg(
        3,
        "data.frames_per_step=8",
        "rollout_validation.every_n_epochs=1",
        "rollout_validation.steps=40",
    )
    train(cfg, tmp_path)
    tags = _events(tmp_path).Tags()["scalars"]
    assert "val_rollout/emd_step_16" in tags and "val_rollout/emd_step_32" not in tags


@pytest.mark.slow
def test_training_killed_mid_epoch_resumes_to_the_same_weights(tmp_path):
    # Six batches an epoch, a checkpoint every step; killed (SIGKILL) after step 3 or 4 of the
    # first epoch, resumed from last.ckpt, it must end with exactly the uninterrupted weights.
    common = [
        *SMALL,
        "data.train_samples_per_epoch=6",
        "data.val_samples=1",
        "data.noise_std=1e-6",
        "trainer.max_steps=9",
        "trainer.max_epochs=-1",
        "trainer.deterministic=true",
        "checkpoint.every_n_train_steps=1",
        "rollout_validation.every_n_epochs=1000",
    ]
    train(compose("train", common), tmp_path / "straight")
    killed = tmp_path / "killed"
    cmd = [sys.executable, "-m", "granular_pyg.train", *common, f"hydra.run.dir={killed}"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if list((killed / "checkpoints").glob("*step=4.ckpt")):  # last.ckpt: step >= 3
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL, "the run ended before it could be killed"
    last = killed / "checkpoints" / "last.ckpt"
    step = torch.load(last, map_location="cpu", weights_only=False)["global_step"]
    assert 3 <= step < 6, f"killed at step {step}: not mid-epoch"
    train(compose("train", [*common, f"ckpt_path={last}"]), tmp_path / "resumed")
    want = torch.load(tmp_path / "straight" / "checkpoints" / "last.ckpt", weights_only=False)
    got = torch.load(tmp_path / "resumed" / "checkpoints" / "last.ckpt", weights_only=False)
    assert got["global_step"] == want["global_step"] == 9
    for name, value in want["state_dict"].items():
        assert torch.equal(got["state_dict"][name], value), name


def test_a_checkpoint_write_that_fails_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    from granular_pyg.training import AtomicCheckpointIO

    io = AtomicCheckpointIO()
    path = tmp_path / "last.ckpt"
    io.save_checkpoint({"global_step": 1}, path)

    def dies_midway(obj, f, *args, **kwargs):
        f.write(b"partial")
        raise KeyboardInterrupt  # as if killed while writing

    monkeypatch.setattr(torch, "save", dies_midway)
    with pytest.raises(KeyboardInterrupt):
        io.save_checkpoint({"global_step": 2}, path)
    monkeypatch.undo()
    assert torch.load(path, weights_only=False)["global_step"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["last.ckpt"]  # no temporary file left
