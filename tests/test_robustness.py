"""Robustness: non-finite predictions stop a rollout keeping its past, bad states are refused
with one clear error, and degenerate scenes (coincident particles, particles on triangle
vertices and edges, zero-area triangles, empty scenes, mixed winding) give finite steps. Ends
with a hypothesis fuzz test of one step on random scenes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from torch_geometric.data import Data

from granular_pyg.errors import InputError, NonFiniteError
from granular_pyg.inference import rollout_trajectory
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import Wall, WallSet
from granular_pyg.simulator import LearnedSimulator
from granular_pyg.transforms import AddRandomWalkNoise

R = 0.0075  # m, cut-off


def _model(normals: str = "both", seed: int = 0) -> LearnedSimulator:
    torch.manual_seed(seed)
    sim = LearnedSimulator(
        Processor(latent=16, num_steps=2, aggr="mean"), radius=R, normals=normals, latent=16
    )
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    return sim.eval()


@pytest.fixture(scope="module")
def hopper():
    return read_trajectory(sample_files("hopper", "test")[0])


def _resting(pos: np.ndarray, history: int = 5) -> torch.Tensor:
    """``[N, H + 1, 3]`` float32 history of particles at rest at ``pos [N, 3]`` (m)."""
    return torch.from_numpy(np.repeat(pos[:, None], history + 1, axis=1)).float()


def _box_walls(extra: list[Wall] | None = None) -> WallSet:
    """A floor: two triangles of the square [-1, 1]^2 cm at z = 0, plus ``extra`` walls."""
    v = np.array([[-0.01, -0.01, 0], [0.01, -0.01, 0], [0.01, 0.01, 0], [-0.01, 0.01, 0]])
    floor = Wall("floor", v, np.array([[0, 1, 2], [0, 2, 3]]))
    return WallSet([floor, *(extra or [])])


# --- non-finite predictions: stop, name the step and particles, keep the past ------------------


def test_nan_prediction_stops_the_rollout_naming_step_and_particles_and_keeps_the_past(hopper):
    sim = _model()
    sim.dt.fill_(0.0025)
    calls = {"n": 0}
    real = sim.predict_acceleration

    def fails_on_third_call(seq, *args, **kwargs):
        acc = real(seq, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 3:
            acc[7] = float("nan")
        return acc

    clean = rollout_trajectory(sim, hopper, steps=2, progress=False)
    sim.predict_acceleration = fails_on_third_call
    with pytest.raises(NonFiniteError, match=r"learned step 2: .*rows \[7\]") as info:
        rollout_trajectory(sim, hopper, steps=5, progress=False)
    exc = info.value
    assert exc.step == 2 and exc.particle_ids == [7]
    partial = exc.partial
    assert partial.num_frames == 6 + 2 and partial.metadata["failed_step"] == 2
    np.testing.assert_array_equal(partial.positions, clean.positions)


@pytest.mark.parametrize(
    ("corrupt", "match"),
    [
        (lambda s: s.__setitem__((4, 2, 0), float("inf")), r"rows \[4\]"),
        (lambda s: s.__setitem__((5, -1, 1), float("nan")), r"NaN in only some coordinates"),
        (lambda s: s.__setitem__((6, 0), float("nan")), r"finite after NaN: rows \[6\]"),
    ],
    ids=["inf", "partly-nan", "back-after-leaving"],
)
def test_bad_particle_states_are_refused_naming_the_rows(hopper, corrupt, match):
    seq = torch.from_numpy(hopper.positions[:6]).permute(1, 0, 2).contiguous()
    corrupt(seq)
    with pytest.raises(InputError, match=match):
        _model().step(seq, WallSet(hopper.scene), 0.0125)


def test_coordinates_too_large_for_float32_are_refused_and_float64_works():
    far = np.array([[100.0, 100.0, 100.0], [100.003, 100.0, 100.0]])
    walls = WallSet(
        [Wall("w", np.array([[100, 99, 99], [101, 99, 99], [100, 101, 99.0]]), [[0, 1, 2]])]
    )
    with pytest.raises(InputError, match=r"dtype=float64"):
        _model().step(_resting(far), walls, 0.0)
    out = _model().step(_resting(far).double(), walls, 0.0)
    assert out.dtype == torch.float64 and torch.isfinite(out).all()


# --- degenerate scenes give finite steps -------------------------------------------------------


def test_coincident_particles_give_a_finite_step():
    pos = np.array([[0.0, 0.0, 0.002], [0.0, 0.0, 0.002], [0.003, 0.0, 0.002]])
    out = _model().step(_resting(pos), _box_walls(), 0.0)
    assert torch.isfinite(out).all()


def test_particles_exactly_on_triangle_vertices_and_edges_give_finite_steps():
    # On a corner vertex, on the shared diagonal edge, on an outer edge: zero distance to the
    # wall, so the wall-node displacement is zero-length.
    pos = np.array([[-0.01, -0.01, 0.0], [0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.005, 0.001]])
    sim = _model()
    graph = sim.build_graph(_resting(pos), _box_walls(), 0.0)
    assert int(graph.is_wall.sum()) >= 3  # a wall node for each particle on the floor
    assert torch.isfinite(graph.x).all() and torch.isfinite(graph.edge_attr).all()
    assert torch.isfinite(sim.step(_resting(pos), _box_walls(), 0.0)).all()


def test_zero_area_triangles_give_finite_steps():
    # Repeated vertex and collinear vertices, right under the particles.
    v = np.array([[0, 0, -0.001], [0.004, 0, -0.001], [0.008, 0, -0.001]])
    sliver = Wall("sliver", v, np.array([[0, 1, 1], [0, 1, 2]]))
    pos = np.array([[0.0, 0.0, 0.001], [0.004, 0.0, 0.0005]])
    out = _model().step(_resting(pos), _box_walls([sliver]), 0.0)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("num_particles", [0, 1])
def test_scenes_with_no_or_one_particle(num_particles):
    pos = np.tile([0.0, 0.0, 0.003], (num_particles, 1))
    out = _model().step(_resting(pos), _box_walls(), 0.0)
    assert out.shape == (num_particles, 3) and torch.isfinite(out).all()


def test_mixed_winding_does_not_change_a_v3_prediction(hopper):
    # Flip a random half of the triangles of every wall: V3 sorts both orientations.
    rng = np.random.default_rng(0)
    flipped = []
    for wall in hopper.scene.walls:
        faces = wall.faces.copy()
        pick = rng.random(len(faces)) < 0.5
        faces[pick] = faces[pick][:, [0, 2, 1]]
        flipped.append(dataclasses.replace(wall, faces=faces))
    seq = torch.from_numpy(hopper.positions[30:36]).permute(1, 0, 2).contiguous()
    seq = seq[torch.isfinite(seq).all(2).all(1)]
    sim = _model("both")
    a = sim.step(seq, WallSet(hopper.scene), 0.09)
    b = sim.step(seq, WallSet(flipped), 0.09)
    torch.testing.assert_close(a, b, rtol=0, atol=1e-9)


# --- fuzz: random scenes, degenerate ones included ---------------------------------------------


@st.composite
def scenes(draw):
    """(positions history [N, 6, 3] float32, walls): random particles near random triangles,
    with coincident particles, particles on vertices and zero-area triangles mixed in."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = draw(st.integers(0, 40))
    num_tri = draw(st.integers(1, 6))
    vertices = rng.uniform(-0.01, 0.01, (3 * num_tri, 3))
    faces = np.arange(3 * num_tri).reshape(num_tri, 3)
    kind = draw(st.sampled_from(["plain", "repeated", "collinear"]))
    if kind == "repeated":
        faces[0, 2] = faces[0, 1]
    elif kind == "collinear":
        vertices[2] = 0.5 * (vertices[0] + vertices[1])
    pos = rng.uniform(-0.012, 0.012, (n, 3))
    if n >= 2 and draw(st.booleans()):
        pos[1] = pos[0]  # coincident
    if n >= 3 and draw(st.booleans()):
        pos[2] = vertices[0]  # on a vertex
    step = rng.normal(0.0, draw(st.sampled_from([0.0, 1e-5, 1e-3])), (n, 6, 3))
    history = pos[:, None] + np.cumsum(step, axis=1)
    gone = rng.random(n) < draw(st.sampled_from([0.0, 0.3, 1.0]))
    history[gone] = np.nan  # particles that have left
    return torch.from_numpy(history).float(), WallSet([Wall("w", vertices, faces)])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes(), st.sampled_from(["none", "single", "both"]), st.sampled_from([0.0, 1e-4]))
def test_noise_and_one_step_on_random_scenes_stay_finite(scene, normals, noise_std):
    # The training transform (random-walk noise, resampled at walls) on the present particles,
    # then one step through the graph transforms (radius graph, wall nodes) and the network.
    seq, walls = scene
    present = torch.isfinite(seq).all(2).all(1)
    if noise_std and bool(present.any()):
        data = Data(pos_seq=seq[present], target_pos=seq[present, -1], walls=walls, time=0.0)
        data = AddRandomWalkNoise(noise_std, True, generator=torch.Generator().manual_seed(0))(data)
        assert torch.isfinite(data.pos_seq).all() and torch.isfinite(data.target_pos).all()
        seq = seq.clone()
        seq[present] = data.pos_seq
    out = _model(normals).step(seq, walls, 0.0)
    assert out.shape == (seq.shape[0], 3)
    assert torch.isfinite(out[present]).all()
    assert torch.isnan(out[~present]).all()


# --- issue 36: nothing lost, nothing silently wrong (in process) ------------------------------


def _rollout_cfg(tmp_path, **extra):
    from omegaconf import OmegaConf

    base = {
        "ckpt": "pretrained:hopper", "trajectory": str(sample_files("hopper", "test")[0]),
        "steps": 6, "start_frame": 0, "dtype": "float32", "skin": None, "wall_guard": False,
        "precision": "32", "threads": 1, "out": str(tmp_path / "p.h5"), "overwrite": False,
        "progress": False, "paraview": False,
    }  # fmt: skip
    return OmegaConf.create(base | extra)


def test_ctrl_c_during_a_rollout_keeps_the_finished_steps_in_a_partial_file(tmp_path, monkeypatch):
    from granular_pyg.errors import Interrupted
    from granular_pyg.rollout import rollout

    real, calls = LearnedSimulator.step, {"n": 0}

    def interrupted_on_the_fourth_step(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real(self, *args, **kwargs)

    monkeypatch.setattr(LearnedSimulator, "step", interrupted_on_the_fourth_step)
    with pytest.raises(Interrupted, match=r"the 3 learned steps finished before it are kept in "):
        rollout(_rollout_cfg(tmp_path))
    partial = read_trajectory(tmp_path / "p.partial.h5")
    assert partial.metadata["interrupted_after_step"] == 3 and partial.num_frames == 6 + 3
    assert not (tmp_path / "p.h5").exists()
    calls["n"] = -10  # interrupted before any step finished: says nothing was kept
    monkeypatch.setattr(
        LearnedSimulator, "step", lambda self, *a, **k: (_ for _ in ()).throw(KeyboardInterrupt)
    )
    with pytest.raises(Interrupted, match="no learned step had finished; nothing was written"):
        rollout(_rollout_cfg(tmp_path, out=str(tmp_path / "q.h5")))


def test_ctrl_c_is_one_error_line_and_exit_status_130(capsys):
    from granular_pyg.cli import EXIT_INTERRUPTED, reports_errors
    from granular_pyg.errors import Interrupted

    @reports_errors
    def main():
        raise Interrupted("the 3 learned steps finished before it are kept in p.partial.h5")

    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == EXIT_INTERRUPTED == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: interrupted (Ctrl-C); the 3 learned steps finished before it are "
                   "kept in p.partial.h5"]  # fmt: skip


def test_strict_booleans_refuse_no_and_flase(tmp_path):
    from granular_pyg.errors import flag
    from granular_pyg.io import check_output

    (tmp_path / "old.h5").write_bytes(b"x")
    with pytest.raises(InputError, match=r"overwrite: expected true or false, got 'no'"):
        check_output(tmp_path / "old.h5", [], "no")
    with pytest.raises(InputError, match=r"wall_guard: expected true or false, got 'flase'"):
        flag("wall_guard", "flase")
    assert (tmp_path / "old.h5").read_bytes() == b"x"


def test_cli_boolean_check_names_every_boolean_option_of_a_config():
    from hydra import compose, initialize_config_dir

    from granular_pyg.cli import check_booleans
    from granular_pyg.config import CONF_DIR

    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        reference = compose("rollout", ["ckpt=x"])
        for key in ("overwrite", "wall_guard", "progress", "paraview"):
            cfg = compose("rollout", ["ckpt=x", f"{key}=no"])
            with pytest.raises(InputError, match=rf"^{key}: expected true or false, got 'no'"):
                check_booleans(cfg, reference)
        check_booleans(compose("rollout", ["ckpt=x", "overwrite=true"]), reference)
        with pytest.raises(InputError, match=r"threads: expected a whole number >= 1, got 0"):
            check_booleans(compose("rollout", ["ckpt=x", "threads=0"]), reference)


def test_particles_all_outside_the_walls_are_refused_and_some_are_warned_about(hopper, capsys):
    from granular_pyg.inference import check_inside_scene, outside_scene

    assert not outside_scene(hopper, 0).any()  # the real hopper: every particle inside
    away = dataclasses.replace(hopper, positions=hopper.positions + np.array([0.5, 0.0, 0.0]))
    with pytest.raises(InputError, match=r"X\.h5: all \d+ particles start outside the walls"):
        check_inside_scene(away, 0, "X.h5")
    some = hopper.positions.copy()
    some[:, :3] += np.array([0.5, 0.0, 0.0])
    assert check_inside_scene(dataclasses.replace(hopper, positions=some), 0, "X.h5") == 3
    assert "warning: X.h5: 3 of" in capsys.readouterr().err


def test_a_trajectory_without_particles_is_refused(hopper):
    empty = dataclasses.replace(
        hopper,
        positions=hopper.positions[:, :0],
        velocities=hopper.velocities[:, :0],
        radii=hopper.radii[:0],
        ids=hopper.ids[:0],
    )
    sim = _model()
    sim.dt.fill_(float(hopper.frame_dt))
    with pytest.raises(InputError, match="the trajectory has no particles"):
        rollout_trajectory(sim, empty, steps=1, progress=False)


def test_fine_tuning_refuses_overrides_it_cannot_honour():
    from omegaconf import OmegaConf

    from granular_pyg.checkpoint.fine_tune import with_initial_model

    cfg = OmegaConf.create(
        {
            "init": "pretrained:hopper",
            "data": {"root": None, "sample": "hopper"},
            "model": {"graph_backend": "scipy"},
        }
    )
    with pytest.raises(InputError, match=r"model\.latent=32: fine-tuning keeps the architecture"):
        with_initial_model(cfg, ["model.latent=32"])
    with pytest.raises(InputError, match=r"model=v1: fine-tuning keeps the model"):
        with_initial_model(cfg, ["model=v1"])
    with pytest.raises(InputError, match=r"data\.noise_std=0\.1: fine-tuning cannot honour it"):
        with_initial_model(cfg, ["data.noise_std=0.1"])
    out, _ = with_initial_model(cfg, ["model.latent=64", "model.graph_backend=scipy"])
    assert out.model.latent == 64 and out.model.graph_backend == "scipy"
    # rules without weights: how walls become nodes, the scene's own frame
    cfg.model = {"wall_nodes": "triangle", "canonical_frame": True}
    out, _ = with_initial_model(cfg, ["model.wall_nodes=triangle", "model.canonical_frame=true"])
    assert out.model.wall_nodes == "triangle" and out.model.canonical_frame is True


def test_negative_or_nan_noise_is_refused():
    from granular_pyg.errors import finite_number

    for value, shown in ((-1e-4, "-0.0001"), (float("nan"), "nan")):
        with pytest.raises(
            InputError, match=rf"data\.noise_std: expected a finite number.*{shown}"
        ):
            finite_number("data.noise_std", value, minimum=0.0)


def test_a_run_folder_on_a_full_disk_is_refused_before_hydra_makes_it(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    from omegaconf import OmegaConf

    from granular_pyg.cli import _check_run_folder

    cfg = OmegaConf.create({"hydra": {"run": {"dir": str(tmp_path / "outputs" / "run")}}})
    _check_run_folder(cfg)  # room enough
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 2**20, 2**20))
    with pytest.raises(InputError, match=r"hydra\.run\.dir: only 1 MiB free for the run folder"):
        _check_run_folder(cfg)
    assert not (tmp_path / "outputs").exists()
