"""Evaluation of rollouts: a perfect prediction scores zero, a perturbed one does not; the
report's files; the paper's variant table and its Wilcoxon tests."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import wilcoxon

from granular_pyg.errors import InputError
from granular_pyg.evaluation import evaluate_pair, variant_table, write_evaluation
from granular_pyg.evaluation.compare import write_variant_figures
from granular_pyg.evaluation.figures import variants_figure
from granular_pyg.evaluation.pair import MIXING_TIME_S
from granular_pyg.evaluation.report import EvaluatedRollout, distinct_names, rollout_label
from granular_pyg.io import read_trajectory, write_trajectory
from granular_pyg.samples import sample_files


def _as_rollout(truth, k: int = 1, history: int = 5, frames: int = 40):
    """The ground truth itself, shaped like a rollout (every k-th frame, initial states first)."""
    idx = np.arange(0, k * frames, k)
    return dataclasses.replace(
        truth,
        positions=truth.positions[idx],
        velocities=truth.velocities[idx],
        times=truth.times[idx],
        metadata={"initial_frames": history + 1, "frames_per_step": k},
    )


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


@pytest.fixture(scope="module")
def drum():
    return read_trajectory(sample_files("drum", "test")[0])


def test_a_perfect_hopper_rollout_scores_zero(hopper):
    ev = evaluate_pair(hopper, _as_rollout(hopper, k=2, frames=60))
    s = ev.scalars
    assert s["steps"] == 54
    assert s["emd_final"] == pytest.approx(0, abs=1e-15)
    assert all(v == pytest.approx(0, abs=1e-15) for v in ev.emd_steps.values())
    assert sorted(ev.emd_steps) == [1, 2, 4, 8, 16, 32]
    assert s["position_mse"] == 0 and s["mean_position_error"] == 0
    assert s["mixing_entropy_error"] == 0 and s["flow_profile_error"] == 0
    assert s["discharge_rate_truth"] > 0 and s["discharge_rate_rel_error"] == 0
    assert s["leaked_particles"] == 0


def test_a_shifted_rollout_is_penalised(hopper):
    pred = _as_rollout(hopper, frames=40)
    pred.positions = pred.positions.copy()
    pred.positions[6:, :, 0] += 0.002  # 2 mm along x after the initial states
    ev = evaluate_pair(hopper, pred)
    assert ev.scalars["position_mse"] == pytest.approx(0.002**2 / 3, rel=1e-3)
    assert ev.scalars["mean_position_error"] > 0.001
    # W2^2 of a set and its 2 mm translate is (2 mm)^2
    assert ev.emd_steps[1] == pytest.approx(0.002**2, rel=1e-3)


def test_a_perfect_drum_rollout_has_no_angle_error(drum):
    ev = evaluate_pair(drum, _as_rollout(drum, frames=200))
    assert ev.observable[0] == "angle"
    assert 20 < ev.scalars["angle_of_repose_truth_deg"] < 45
    assert ev.scalars["angle_of_repose_error_deg"] == 0
    assert ev.scalars["angle_of_repose_curve_error_deg"] == 0
    swing = ev.scalars["centre_of_mass_swing_truth_m"]
    times = ev.series["times"]
    if times[-1] - times[0] > 1.0:  # a settled part to measure
        assert 0 <= swing == ev.scalars["centre_of_mass_swing_pred_m"] < 0.01
    else:
        assert np.isnan(swing)


def test_a_drum_bed_swinging_about_the_right_median_shows_in_the_curve_error(drum):
    """The prediction's second half is the truth's frames in reverse order: the same median
    angle (error 0), but frame by frame the mean of |angle difference| (brute force here)."""
    pred = _as_rollout(drum, frames=200)
    half = len(pred.times) // 2
    pred.positions = pred.positions.copy()
    pred.positions[half:] = pred.positions[half:][::-1]
    ev = evaluate_pair(drum, pred)
    assert ev.scalars["angle_of_repose_error_deg"] == pytest.approx(0, abs=1e-9)
    ang_t, ang_p = ev.series["angle_truth"][half:], ev.series["angle_pred"][half:]
    expected = np.nanmean(np.abs(ang_p - ang_t))
    assert ev.scalars["angle_of_repose_curve_error_deg"] == pytest.approx(expected)
    assert expected > 0.5


def test_evaluate_pair_rejects_a_foreign_prediction(hopper, drum):
    with pytest.raises(InputError, match="particles against the truth"):
        evaluate_pair(hopper, _as_rollout(drum))


def test_the_evaluation_folder_holds_json_csv_figures_and_report(tmp_path, hopper):
    ev = evaluate_pair(hopper, _as_rollout(hopper, frames=30))
    rollouts = [EvaluatedRollout("test", "traj_0003.h5", "truth.h5", "pred.h5", ev)]
    report = write_evaluation(tmp_path, rollouts, {"variant": "V3", "ckpt": "x.ckpt"})
    text = report.read_text()
    assert "| emd_mean |" in text and "figures/test_traj_0003.png" in text
    summary = json.loads((tmp_path / "evaluation.json").read_text())
    assert summary["variant"] == "V3" and summary["means"]["test"]["steps"] == 24
    with (tmp_path / "emd_steps.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["step"]) for r in rows] == [1, 2, 4, 8, 16]
    assert (tmp_path / "figures" / "test_traj_0003.png").read_bytes()[:4] == b"\x89PNG"
    assert any((tmp_path / "tensorboard").glob("events.out.tfevents.*"))


def _fake_run(folder, variant, values):
    folder.mkdir(parents=True)
    (folder / "evaluation.json").write_text(json.dumps({"variant": variant}))
    with (folder / "emd_steps.csv").open("w") as fh:
        fh.write("split,trajectory,step,emd\n")
        for (split, traj, step), v in values.items():
            fh.write(f"{split},{traj},{step},{v}\n")
    return folder


def test_variant_table_matches_scipy_on_paired_values(tmp_path):
    rng = np.random.default_rng(0)
    keys = [(s, f"t{i}", 2**j) for s in ("train", "test") for i in range(3) for j in range(5)]
    v3 = {k: float(rng.uniform(1e-5, 1e-4)) for k in keys}
    v1 = {k: v * float(rng.uniform(1.0, 3.0)) for k, v in v3.items()}  # V1 worse everywhere
    runs = [
        _fake_run(tmp_path / "a", "V3", v3),
        _fake_run(tmp_path / "b", "V1", v1),
        _fake_run(tmp_path / "c", "V1", v1),  # a second seed, identical: the mean is v1
    ]
    rows, markdown = variant_table(runs)
    by = {r["variant"]: r for r in rows}
    test_keys = [k for k in keys if k[0] == "test"]
    a = np.array([v3[k] for k in sorted(test_keys)])
    b = np.array([v1[k] for k in sorted(test_keys)])
    assert by["V1"]["test_mu"] == pytest.approx(b.mean())
    assert by["V1"]["test_sigma"] == pytest.approx(b.std())
    assert by["V1"]["runs"] == 2 and by["V3"]["test_n"] == 15
    expected = wilcoxon(a - b, alternative="less").pvalue
    assert by["V1"]["test_p_ref_less"] == pytest.approx(expected)
    assert by["V1"]["test_p_ref_less"] < 1e-3 < by["V1"]["test_p_row_less"]
    assert np.isnan(by["V3"]["test_p_ref_less"])
    assert "| V1 | 2 |" in markdown and "p (V3 < row)" in markdown


def test_variant_table_needs_the_reference_and_real_folders(tmp_path):
    run = _fake_run(tmp_path / "a", "V1", {("test", "t", 1): 1.0})
    with pytest.raises(InputError, match="no run of variant 'V3'"):
        variant_table([run])
    with pytest.raises(InputError, match="not an evaluation folder"):
        variant_table([tmp_path])


def test_a_long_step_rollout_splits_the_mixing_classes_at_the_papers_time(hopper):
    """k = 8 (20 ms frames) on the hopper: the classes are split at the first frame at or after
    t0 = 0.03 s (frame 2), while the bed is whole, so the entropy curve is not degenerate."""
    rollout = _as_rollout(hopper, k=8, frames=26)
    ev = evaluate_pair(hopper, rollout)
    assert ev.mixing_frame == 2 and rollout.times[2] >= MIXING_TIME_S > rollout.times[1]
    entropy = ev.series["entropy_truth"]
    assert ev.scalars["mixing_entropy_error"] == 0  # the truth against itself
    assert np.nanmax(entropy) > entropy[2] > 0  # mixing as the bed drains


def test_variant_figures_plot_the_truth_and_each_variants_first_run(tmp_path, hopper):
    truth_file = sample_files("hopper", "test")[0]
    exact = _as_rollout(hopper, k=2, frames=30)
    shifted = dataclasses.replace(exact, positions=exact.positions + np.float32(0.001))
    runs = []
    for variant, pred in [("V3", exact), ("V1", shifted), ("V3", shifted)]:
        run = tmp_path / f"{variant}_{len(runs)}"
        write_trajectory(pred, run / "rollouts" / "test.h5")
        ev = evaluate_pair(hopper, pred)
        rollout = EvaluatedRollout(
            "test", truth_file.name, str(truth_file), str(run / "rollouts" / "test.h5"), ev
        )
        write_evaluation(run, [rollout], {"variant": variant, "ckpt": "x.ckpt"})
        runs.append(run)
    [path] = write_variant_figures(runs, tmp_path / "compare")
    assert path.name == f"variants_test_{truth_file.stem}.png"
    assert path.read_bytes()[:4] == b"\x89PNG"
    # the figure itself: four panels, each with the truth and one curve per variant
    evaluations = {"V1": evaluate_pair(hopper, shifted), "V3": evaluate_pair(hopper, exact)}
    fig = variants_figure(evaluations)
    assert len(fig.axes) == 4
    for ax in fig.axes:
        assert [line.get_label() for line in ax.lines] == ["LIGGGHTS", "V1", "V3"]
    truth_z, v3_z = fig.axes[0].lines[0].get_ydata(), fig.axes[0].lines[2].get_ydata()
    assert np.array_equal(truth_z, v3_z, equal_nan=True)  # V3 is the truth itself
    with pytest.raises(InputError, match="at least one variant"):
        variants_figure({})


def test_evaluate_selects_files_by_glob_or_by_split(tmp_path):
    from granular_pyg.config import compose
    from granular_pyg.evaluate import selected_files
    from granular_pyg.samples import SAMPLES_DIR

    hoppers = str(SAMPLES_DIR / "hopper" / "traj_000[12].h5")
    cfg = compose("evaluate", ["ckpt=x", f"trajectories=['{hoppers}']", "out=."])
    files = selected_files(cfg, None, "hopper")
    assert list(files) == ["files"] and [f.name for f in files["files"]] == [
        "traj_0001.h5",
        "traj_0002.h5",
    ]
    by_split = selected_files(compose("evaluate", ["ckpt=x", "out=."]), None, "hopper")
    assert list(by_split) == ["test"] and len(by_split["test"]) == 1
    with pytest.raises(InputError, match="matches no file"):
        selected_files(compose("evaluate", ["ckpt=x", "trajectories=[nothing*.h5]"]), None, None)
    one = SAMPLES_DIR / "hopper" / "traj_0000.h5"
    with pytest.raises(InputError, match=r"is a file; .*trajectories="):
        selected_files(compose("evaluate", ["ckpt=x"]), str(one), None)


def test_a_rollout_that_drains_twice_as_fast_scores_worse_on_the_same_frames(hopper):
    """Frame f of the fast rollout is the truth's frame min(2f, T - 1): it empties the hopper
    while the truth still holds particles. Those frames count (the remaining particles' move to
    the outlet), so it scores worse than a rollout 1 mm off the truth, over as many frames."""
    exact = _as_rollout(hopper, k=4, frames=50)
    idx = np.minimum(2 * np.arange(50), 49)
    fast = dataclasses.replace(
        exact, positions=exact.positions[idx], velocities=2 * exact.velocities[idx]
    )
    offset = dataclasses.replace(exact, positions=exact.positions.copy())
    offset.positions[6:, :, 0] += 0.001
    ev_fast, ev_offset = evaluate_pair(hopper, fast), evaluate_pair(hopper, offset)
    count = {
        name: np.isfinite(traj.positions[5 + np.array([1, 2, 4, 8, 16, 32])]).all(-1).sum(1)
        for name, traj in (("fast", fast), ("truth", exact))
    }
    assert ((count["fast"] == 0) & (count["truth"] > 0)).any()  # frames the old mean left out
    assert ev_fast.scalars["emd_frames"] == ev_offset.scalars["emd_frames"] == 6
    assert sorted(ev_fast.emd_steps) == sorted(ev_offset.emd_steps) == [1, 2, 4, 8, 16, 32]
    assert ev_fast.scalars["emd_mean"] > ev_offset.scalars["emd_mean"] > 0


def test_a_particle_moved_through_the_hopper_wall_is_one_leak(hopper):
    pred = _as_rollout(hopper, frames=40)
    pred.positions = pred.positions.copy()
    stays = np.flatnonzero(np.isfinite(pred.positions).all((0, 2)))[0]
    x_out = hopper.scene.domain_hi[0] - 0.001  # beyond the V, inside the box
    pred.positions[20:, stays] = [x_out, 0.0, 0.05]
    s = evaluate_pair(hopper, pred).scalars
    assert s["leaked_particles"] == 1 and s["leaked_particles_truth"] == 0


def test_a_scene_of_kind_other_skips_what_it_cannot_have_with_a_warning(hopper):
    other = dataclasses.replace(hopper, scene=dataclasses.replace(hopper.scene, kind="other"))
    with pytest.warns(UserWarning) as record:
        ev = evaluate_pair(other, _as_rollout(other, k=2, frames=40))
    [message] = [str(w.message) for w in record]
    for name in ("mixing entropy", "discharge rate", "dynamic angle of repose"):
        assert name in message
    s = ev.scalars
    skipped = ["mixing_entropy_error", "discharge_rate_rel_error", "angle_of_repose_error_deg"]
    assert all(np.isnan(s[k]) for k in skipped)
    assert s["emd_mean"] == pytest.approx(0, abs=1e-15)  # the others are still there
    assert s["leaked_particles"] == 0
    assert ev.observable[0] == "discharged" and ev.series["discharged_truth"][-1] > 0.5


def _swap_xy(traj):
    """The trajectory mirrored to exchange x and y, walls and rotation axis too (a mirror turns
    the other way round)."""
    swap = [1, 0, 2]
    scene = traj.scene
    walls = [
        dataclasses.replace(
            w,
            vertices=w.vertices[:, swap],
            motion=dataclasses.replace(
                w.motion, axis=tuple(np.asarray(w.motion.axis)[swap]), omega=-w.motion.omega
            ),
        )
        for w in scene.walls
    ]
    lo, hi = np.asarray(scene.domain_lo)[swap], np.asarray(scene.domain_hi)[swap]
    scene = dataclasses.replace(scene, walls=walls, domain_lo=tuple(lo), domain_hi=tuple(hi))
    return dataclasses.replace(
        traj,
        positions=traj.positions[..., swap],
        velocities=traj.velocities[..., swap],
        scene=scene,
    )


def test_the_drum_axis_comes_from_its_rotating_wall(drum):
    """The same drum turning about x instead of y: the same angle of repose and mixing."""
    pred = _as_rollout(drum, frames=120)
    pred.positions = pred.positions.copy()
    pred.positions[6:] += np.float32(0.001)
    ev = evaluate_pair(drum, pred)
    turned = _swap_xy(drum)
    assert turned.scene.walls[0].motion.axis == (1.0, 0.0, 0.0)
    ev_x = evaluate_pair(turned, _swap_xy(pred))
    for key in ("angle_of_repose_truth_deg", "angle_of_repose_pred_deg", "mixing_entropy_error"):
        assert ev_x.scalars[key] == pytest.approx(ev.scalars[key], rel=1e-9)
    assert ev_x.scalars["leaked_particles_truth"] == 0


def test_the_hopper_outlet_height_comes_from_its_params(hopper):
    """The hopper and its bed lifted by 5 cm with params outlet_z = 0.05: the same discharge."""
    lift = np.array([0.0, 0.0, 0.05])
    scene = hopper.scene
    walls = [dataclasses.replace(w, vertices=w.vertices + lift) for w in scene.walls]
    raised = dataclasses.replace(
        scene,
        walls=walls,
        domain_lo=tuple(np.asarray(scene.domain_lo) + lift),
        domain_hi=tuple(np.asarray(scene.domain_hi) + lift),
        outflow_z=scene.outflow_z + 0.05,
        params={**scene.params, "outlet_z": 0.05},
    )
    lifted = dataclasses.replace(hopper, positions=hopper.positions + lift, scene=raised)
    ev = evaluate_pair(hopper, _as_rollout(hopper, k=2, frames=60))
    ev_up = evaluate_pair(lifted, _as_rollout(lifted, k=2, frames=60))
    assert ev_up.scalars["discharge_rate_truth"] == pytest.approx(
        ev.scalars["discharge_rate_truth"], rel=1e-6
    )
    assert ev_up.scalars["discharge_rate_truth"] > 0
    assert ev_up.scalars["leaked_particles_truth"] == 0


def test_trajectories_of_several_families_keep_distinct_names_and_files():
    files = [Path("data/h/cone/traj_0011.h5"), Path("data/h/silo/traj_0011.h5"), Path("x/t_2.h5")]
    assert distinct_names(files) == ["cone/traj_0011.h5", "silo/traj_0011.h5", "t_2.h5"]
    assert [rollout_label("test", n) for n in distinct_names(files)] == [
        "test_cone-traj_0011",
        "test_silo-traj_0011",
        "test_t_2",
    ]
    # the same name in folders that differ only higher up: as many parts as it takes
    assert distinct_names([Path("a/x/t.h5"), Path("b/x/t.h5")]) == ["a/x/t.h5", "b/x/t.h5"]


def test_evaluate_runs_no_further_than_the_ground_truth_with_a_warning(hopper, capsys):
    from granular_pyg.evaluate import _steps_within
    from granular_pyg.inference import available_steps, initial_frames, load_simulator

    sim, _ = load_simulator("pretrained:hopper")
    k, initial = initial_frames(sim, hopper)
    available = available_steps(sim, hopper)
    # the frames left after the last initial state, in whole learned steps
    assert available == (hopper.num_frames - 1 - int(initial[-1])) // k > 0
    assert _steps_within(available + 7, sim, hopper, "bundled") == available
    assert "runs past its last frame" in capsys.readouterr().err
    assert _steps_within(available, sim, hopper, "bundled") == available
    assert _steps_within(None, sim, hopper, "bundled") is None
    assert capsys.readouterr().err == ""
    # a later start leaves k fewer frames per k frames skipped
    assert _steps_within(available, sim, hopper, "bundled", start_frame=2 * k) == available - 2
    assert "runs past its last frame" in capsys.readouterr().err
