"""`python -m granular_pyg.generate`: plans, splits, and real LIGGGHTS runs end to end."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from granular_pyg.errors import InputError
from granular_pyg.generate import (
    _without_ranges_if_asked,
    generate,
    plan_trajectories,
    split_counts,
    trajectory_digest,
)
from granular_pyg.io import read_trajectory

REPO = Path(__file__).resolve().parents[1]
# A tiny real hopper: a few hundred particles, a handful of frames, seconds of LIGGGHTS.
TINY = [
    "scene=hopper",
    "scene.build.num_particles=200",
    "scene.build.duration=0.03",
    "scene.build.frame_dt=0.005",
    "scene.build.t_open=0.01",
    "scene.build.settle_time=0.15",
    "scene.ranges.num_particles=[150,200]",
    "progress=false",
]
# The digests of TINY's n=3 dataset as first generated (Debian's LIGGGHTS 3.8, x86-64): a
# regeneration on any machine must give the same bits.
TINY_DIGESTS = {
    "traj_0000.h5": "b1dacf625fc332708929917f2253157bfd7d8c1e769a7d512ae9592b7e04c640",
    "traj_0001.h5": "8a4175b70409278abb157ee948e66e6216562651dd89927f9f5f4bb6ea74f5b1",
    "traj_0002.h5": "c643fac1a05461688b1767404415c81e8c1421f3d0f80b436651ab471e27d1b3",
}


def _cfg(*overrides: str):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        return compose("generate", overrides=list(overrides))


def test_split_counts_keep_one_valid_and_test_trajectory():
    assert split_counts(4, {"train": 0.8, "valid": 0.1, "test": 0.1}) == {
        "valid": 1,
        "test": 1,
        "train": 2,
    }
    assert split_counts(40, {"train": 0.75, "valid": 0.125, "test": 0.125})["train"] == 30
    with pytest.raises(InputError, match="no training trajectory"):
        split_counts(2, {"valid": 0.5, "test": 0.5})


def test_plan_is_deterministic_per_index_and_samples_the_ranges():
    cfg = _cfg("n=6", "seed=5")
    plan = plan_trajectories(cfg)
    again = plan_trajectories(_cfg("n=8", "seed=5"))
    assert [e["params"] for e in plan] == [e["params"] for e in again[:6]]  # n does not reshuffle
    assert len({e["seed"] for e in plan}) == 6
    for entry in plan:
        alpha = entry["params"]["alpha_deg"]
        count = entry["params"]["num_particles"]
        assert 50.0 <= alpha <= 80.0 and isinstance(alpha, float)
        assert 1600 <= count <= 2400 and isinstance(count, int)
    assert [e["split"] for e in plan].count("test") == 1


def test_unknown_range_key_is_named():
    cfg = _cfg("+scene.ranges.colour=[1,2]")
    with pytest.raises(InputError, match=r"\['colour'\] are not parameters"):
        plan_trajectories(cfg)


@pytest.mark.parametrize("override", ["scene.ranges={}", "scene.ranges=null", "~scene.ranges"])
def test_every_way_of_saying_no_ranges_samples_nothing(override):
    from hydra import compose as hydra_compose
    from hydra.core.hydra_config import HydraConfig

    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = hydra_compose("generate", [override, "n=3"], return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    plan = plan_trajectories(_without_ranges_if_asked(cfg))
    build = {k: v for k, v in cfg.scene.build.items()}
    assert all(e["params"] == build for e in plan)


@pytest.mark.slow
def test_generate_runs_liggghts_writes_hdf5_and_resumes(tmp_path):
    out = tmp_path / "data"
    manifest_path = generate(_cfg(*TINY, "n=3", f"out={out}"))
    manifest = json.loads(manifest_path.read_text())
    assert manifest["splits"] == {
        "train": ["traj_0000.h5"],
        "valid": ["traj_0001.h5"],
        "test": ["traj_0002.h5"],
    }
    traj = read_trajectory(out / "traj_0000.h5")
    entry = manifest["trajectories"][0]
    assert traj.positions.shape == (7, entry["params"]["num_particles"], 3)
    assert np.allclose(np.diff(traj.times), 0.005)
    assert traj.metadata["liggghts_version"].startswith("LIGGGHTS (Version LIGGGHTS-PUBLIC")
    assert traj.metadata["seed"] == entry["seed"]
    assert traj.scene is not None and traj.scene.wall("lid").removal_time == 0.01
    assert np.isfinite(traj.positions[0]).all()
    assert not (out / ".work").exists()

    assert {e["file"]: e["sha256"] for e in manifest["trajectories"]} == TINY_DIGESTS

    # Resume: only the missing trajectory is made again, the others are untouched, and the
    # new one is bit-identical (its digest equals the manifest's).
    stamp = (out / "traj_0000.h5").stat().st_mtime_ns
    digest = manifest["trajectories"][2]["sha256"]
    assert digest == trajectory_digest(read_trajectory(out / "traj_0002.h5"))
    (out / "traj_0002.h5").unlink()
    generate(_cfg(*TINY, "n=3", f"out={out}"))
    assert trajectory_digest(read_trajectory(out / "traj_0002.h5")) == digest
    assert (out / "traj_0000.h5").stat().st_mtime_ns == stamp

    # A regeneration that does not reproduce the recorded bits is an error naming the file;
    # the manifest keeps the digest it recorded first.
    tampered = json.loads(manifest_path.read_text())
    tampered["trajectories"][2]["sha256"] = "0" * 64
    manifest_path.write_text(json.dumps(tampered))
    (out / "traj_0002.h5").unlink()
    with pytest.raises(
        InputError, match=r"traj_0002.h5: 000000000000 -> c643fac1a054.*bit for bit"
    ):
        generate(_cfg(*TINY, "n=3", f"out={out}"))
    assert json.loads(manifest_path.read_text())["trajectories"][2]["sha256"] == "0" * 64
    manifest_path.write_text(json.dumps(manifest))

    # Other settings into the same folder: refused, naming the keys; nothing moves.
    before = manifest_path.read_text()
    with pytest.raises(InputError, match=r"scene_config.build.alpha_deg: 60.0 -> 70.0.*new out="):
        generate(_cfg(*TINY, "n=3", f"out={out}", "scene.build.alpha_deg=70.0", "~scene.ranges"))
    with pytest.raises(InputError, match=r"n: 3 -> 4"):
        generate(_cfg(*TINY, "n=4", f"out={out}"))
    assert manifest_path.read_text() == before


@pytest.mark.slow
def test_killed_generation_leaves_no_partial_file_and_resumes(tmp_path):
    out = tmp_path / "data"
    cmd = [sys.executable, "-m", "granular_pyg.generate", *TINY, "n=1", "jobs=1", f"out={out}"]
    cmd[cmd.index("scene.build.duration=0.03")] = "scene.build.duration=0.5"
    proc = subprocess.Popen(cmd, cwd=REPO, start_new_session=True)
    deadline = time.time() + 120
    while not list(out.glob(".work/*/traj.dump")) and time.time() < deadline:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # kill python and LIGGGHTS mid-trajectory
    proc.wait()
    assert not list(out.glob("*.h5")) and not list(out.glob(".*.tmp"))
    subprocess.run(cmd, cwd=REPO, check=True, timeout=300)
    assert read_trajectory(out / "traj_0000.h5").num_frames == 101  # 0.5 s every 5 ms


def test_nested_parameters_are_sampled_through_dotted_range_keys():
    plan = plan_trajectories(
        _cfg(
            "n=3",
            "+scene.ranges.materials.friction=[0.3,0.7]",
            "+scene.ranges.bin_height=[0.0,0.05]",
        )
    )
    frictions = [e["params"]["materials"]["friction"] for e in plan]
    assert all(0.3 <= f <= 0.7 for f in frictions) and len(set(frictions)) == 3
    assert all(e["params"]["materials"]["restitution"] == 0.6 for e in plan)
    with pytest.raises(InputError, match=r"materials.colour"):
        plan_trajectories(_cfg("+scene.ranges.materials.colour=[1,2]"))


@pytest.mark.slow
def test_a_wedge_hopper_under_a_bin_generates_and_keeps_every_particle_inside(tmp_path):
    from granular_pyg.metrics import leaked_particles

    out = tmp_path / "bin"
    generate(_cfg(*TINY, "n=1", f"out={out}", "scene.build.bin_height=0.03", "family=wedge_bin"))
    manifest = json.loads((out / "manifest.json").read_text())
    assert (
        manifest["family"] == "wedge_bin" and manifest["trajectories"][0]["family"] == "wedge_bin"
    )
    traj = read_trajectory(out / "traj_0000.h5")
    assert traj.scene.params["bin_height"] == 0.03 and traj.scene.domain_hi[2] > 0.13
    assert leaked_particles(traj.positions, traj.scene, traj.times) == 0
