"""Particle-property inputs: ``model.radius_feature`` and ``model.material_features``.

Off (the default) the features are exactly today's; on, the radius column is radius / R on the
particles and 0 on the wall nodes, each material column the scaled value on every node, the
properties follow the particles through ``step``'s mask, push-forward and unrolled training, and
a model built with them refuses to run without them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from granular_pyg.config import compose
from granular_pyg.data.windows import WindowDataset
from granular_pyg.errors import InputError
from granular_pyg.inference import load_simulator, rollout_trajectory
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import Materials, WallSet
from granular_pyg.simulator import MATERIAL_FEATURES, LearnedSimulator, ParticleProps
from granular_pyg.training.data_module import _Collate
from granular_pyg.training.objectives import PushForward, Unrolled

FRAME = 30  # flowing, lid gone, particles at the walls
CUTOFF = 0.0075
BASE_WIDTH = 3 * 5 + 6 + 2
ALL_MATERIALS = list(MATERIAL_FEATURES)


@pytest.fixture(scope="module")
def hopper():
    traj = read_trajectory(sample_files("hopper")[0])
    window = torch.from_numpy(traj.positions[FRAME - 5 : FRAME + 1]).permute(1, 0, 2)
    present = torch.isfinite(window).all(2).all(1)
    return traj, window[present].contiguous(), present, float(traj.times[FRAME])


def _model(seed=0, **kwargs) -> LearnedSimulator:
    torch.manual_seed(seed)
    options = dict(radius=CUTOFF, normals="both", latent=16, dt=0.0025) | kwargs
    sim = LearnedSimulator(Processor(latent=16, num_steps=2, aggr="mean"), **options)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    return sim.eval()


def _features_as_before(sim: LearnedSimulator, pos_seq, walls, time) -> torch.Tensor:
    """Node features as ``LearnedSimulator._features`` computed them before these options."""
    from torch_geometric.data import Data

    data = sim.wall_nodes(sim.radius_graph(Data(pos=pos_seq[:, -1], walls=walls, time=time)))
    num_real = data.num_real
    vel = (sim.velocities(pos_seq).float() - sim.vel_mean) / sim.vel_std
    wall_vel = (data.wall_vel[num_real:].float() - sim.vel_mean) / sim.vel_std
    vel_feat = torch.cat([vel.flatten(1), wall_vel.repeat(1, sim.history)])
    kind = torch.nn.functional.one_hot(data.is_wall.long(), 2).float()
    x = torch.cat([vel_feat, data.normal_feat.float(), kind], dim=1)
    return x * data.node_weight.float().unsqueeze(1)


def _props(traj, present=None, radius=None, **materials) -> ParticleProps:
    radii = torch.from_numpy(traj.radii) if radius is None else torch.as_tensor(radius)
    mats = dataclasses.replace(traj.scene.materials, **materials)
    props = ParticleProps(radii, mats)
    return props[present] if present is not None else props


# -- off: today's features ----------------------------------------------------------------------


def test_off_the_features_and_weights_are_todays(hopper):
    traj, seq, present, t = hopper
    walls = WallSet(traj.scene)
    sim = _model()
    before = _features_as_before(sim, seq, walls, t)
    graph = sim.build_graph(seq, walls, t)
    assert graph.x.shape[1] == BASE_WIDTH
    assert torch.equal(graph.x, before)
    # given properties, a model without the options ignores them
    with_props = sim.build_graph(seq, walls, t, props=_props(traj, present, friction=0.9))
    assert torch.equal(with_props.x, before)
    # the same weights as a model of before (encoder input width 3H + 8)
    shapes = {
        k: v.shape
        for k, v in _model(radius_feature=False, material_features=[]).state_dict().items()
    }
    assert shapes == {k: v.shape for k, v in sim.state_dict().items()}
    assert sim.uses_props is False


def test_the_config_defaults_are_off():
    cfg = compose("train", ["model.latent=16"])
    assert cfg.model.radius_feature is False and list(cfg.model.material_features) == []
    sim = instantiate(cfg.model)
    assert not sim.radius_feature and sim.material_features == ()


# -- on: the columns ---------------------------------------------------------------------------


def test_the_radius_column_is_radius_over_cutoff_and_zero_on_walls(hopper):
    traj, seq, present, t = hopper
    walls = WallSet(traj.scene)
    sim = _model(radius_feature=True)
    n = seq.shape[0]
    small = sim.build_graph(
        seq, walls, t, props=_props(traj, present, radius=torch.full((n,), 1e-3))
    )
    large = sim.build_graph(
        seq, walls, t, props=_props(traj, present, radius=torch.full((n,), 2e-3))
    )
    assert small.x.shape[1] == BASE_WIDTH + 1
    assert torch.equal(small.edge_index, large.edge_index)
    # identical but for the radius: only the last column differs
    assert torch.equal(small.x[:, :-1], large.x[:, :-1])
    assert torch.equal(small.x[:, :-1], _features_as_before(sim, seq, walls, t))
    wall = small.is_wall
    assert wall.any()
    torch.testing.assert_close(
        small.x[~wall, -1], torch.full((n,), 1e-3 / CUTOFF), rtol=1e-6, atol=0
    )
    torch.testing.assert_close(
        large.x[~wall, -1], torch.full((n,), 2e-3 / CUTOFF), rtol=1e-6, atol=0
    )
    assert (small.x[wall, -1] == 0).all() and (large.x[wall, -1] == 0).all()
    # the outputs differ too
    assert not torch.allclose(sim(small), sim(large))
    # a polydisperse bed: each particle its own radius
    radii = torch.linspace(1e-3, 2e-3, n)
    mixed = sim.build_graph(seq, walls, t, props=_props(traj, present, radius=radii))
    torch.testing.assert_close(mixed.x[~wall, -1], radii / CUTOFF, rtol=1e-6, atol=0)


def test_the_contact_column_is_length_over_the_summed_radii(hopper):
    """Brute force per edge: |x_i - x_j| / (r_i + r_j), a wall node's radius 0; the other
    columns are untouched, and 1 means contact for any particle size."""
    traj, seq, present, t = hopper
    walls = WallSet(traj.scene)
    n = seq.shape[0]
    radii = torch.linspace(1e-3, 2e-3, n)
    plain = _model(radius_feature=True)
    sim = _model(radius_feature=True, contact_feature=True)
    props = _props(traj, present, radius=radii)
    graph = sim.build_graph(seq, walls, t, props=props)
    before = plain.build_graph(seq, walls, t, props=props)
    assert graph.edge_attr.shape[1] == 5
    assert torch.equal(graph.edge_attr[:, :4], before.edge_attr)
    pos = torch.cat([seq[:, -1].double(), walls.contacts(seq[:, -1], CUTOFF, t).closest.double()])
    src, dst = graph.edge_index
    wall_edge = src >= n
    assert wall_edge.any() and (~wall_edge).any()
    node_radius = torch.cat([radii.double(), torch.zeros(pos.shape[0] - n, dtype=torch.float64)])
    expected = (pos[dst] - pos[src]).norm(dim=1) / (node_radius[src] + node_radius[dst])
    torch.testing.assert_close(graph.edge_attr[:, 4].double(), expected, rtol=1e-5, atol=1e-6)
    # particles twice as large: the same edges, every edge half as many contact distances long
    twice = sim.build_graph(seq, walls, t, props=_props(traj, present, radius=2 * radii))
    torch.testing.assert_close(twice.edge_attr[:, 4], graph.edge_attr[:, 4] / 2)
    assert sim.model.edge_encoder[0].in_features == 5
    assert plain.model.edge_encoder[0].in_features == 4


def test_the_material_columns_are_the_scaled_values_on_every_node(hopper):
    traj, seq, present, t = hopper
    walls = WallSet(traj.scene)
    sim = _model(material_features=["friction"])
    graph = sim.build_graph(seq, walls, t, props=_props(traj, present, friction=0.37))
    assert graph.x.shape[1] == BASE_WIDTH + 1 and graph.is_wall.any()
    assert torch.equal(graph.x[:, -1], torch.full((graph.x.shape[0],), 0.37))
    assert torch.equal(graph.x[:, :-1], _features_as_before(sim, seq, walls, t))

    mats = Materials(
        youngs_modulus=5e7, poisson_ratio=0.25, restitution=0.4, friction=0.6,
        rolling_friction=0.05, density=2000.0,
    )  # fmt: skip
    sim = _model(radius_feature=True, material_features=ALL_MATERIALS)
    props = ParticleProps(torch.from_numpy(traj.radii), mats)[present]
    graph = sim.build_graph(seq, walls, t, props=props)
    assert graph.x.shape[1] == BASE_WIDTH + 1 + 6
    expected = [0.6, 0.05 * 10, 0.4, math.log10(5e7 / 5e6), 0.25, 2000.0 / 2500]
    for col, value in enumerate(expected):
        column = graph.x[:, BASE_WIDTH + 1 + col]
        torch.testing.assert_close(column, torch.full_like(column, value), rtol=1e-6, atol=1e-7)
    # a mapping of the fields does as well as Materials
    as_dict = ParticleProps(props.radius, dataclasses.asdict(mats))
    assert torch.equal(sim.build_graph(seq, walls, t, props=as_dict).x, graph.x)


def test_the_encoder_input_grows_by_the_columns():
    def width(sim):
        return next(p for p in sim.model.parameters() if p.dim() == 2).shape[1]

    assert width(_model()) == BASE_WIDTH
    assert width(_model(radius_feature=True)) == BASE_WIDTH + 1
    assert width(_model(radius_feature=True, material_features=["friction", "density"])) == (
        BASE_WIDTH + 3
    )


@pytest.mark.parametrize(
    "options",
    [{"material_features": ["stiffness"]}, {"material_features": ["friction", "friction"]},
     {"radius_feature": "yes"}, {"contact_feature": 1}],
)  # fmt: skip
def test_bad_options_are_refused(options):
    with pytest.raises(
        InputError, match=r"model\.(material_features|radius_feature|contact_feature)"
    ):
        _model(**options)


# -- the carrier: sliced with the particles, required when needed --------------------------------


def test_step_slices_the_properties_like_the_positions(hopper):
    """Particles absent (NaN rows) or present in any pattern: ``step`` with all ``N`` rows of
    the properties equals a brute-force loop that gathers the present particles' rows."""
    traj, _, _, t = hopper
    sim = _model(radius_feature=True, material_features=["friction", "density"])
    seq = torch.from_numpy(traj.positions[FRAME - 5 : FRAME + 1]).permute(1, 0, 2).double()
    n = seq.shape[0]
    gen = torch.Generator().manual_seed(3)
    seq[torch.rand(n, generator=gen) < 0.3] = float("nan")  # some more have left
    radii = 1e-3 + 1e-3 * torch.rand(n, generator=gen, dtype=torch.float64)
    props = ParticleProps(radii, dataclasses.replace(traj.scene.materials, friction=0.3))
    walls = WallSet(traj.scene)
    out = sim.step(seq, walls, t, props=props)

    rows = [i for i in range(n) if bool(torch.isfinite(seq[i]).all())]
    assert 0 < len(rows) < n
    sub = ParticleProps(torch.stack([radii[i] for i in rows]), props.materials)
    with torch.no_grad():
        acc = sim.predict_acceleration(seq[rows], walls, t, props=sub)
    expected = torch.full_like(seq[:, -1], float("nan"))
    expected[rows] = sim.integrate(seq[rows], acc.double())
    torch.testing.assert_close(out, expected, rtol=0, atol=0, equal_nan=True)
    # the radii matter: the same positions with the radii reversed move differently
    flipped = sim.step(seq, walls, t, props=ParticleProps(radii.flip(0), props.materials))
    assert not torch.allclose(flipped[rows], out[rows])

    # a rollout passes them to every step
    two = sim.rollout(seq, walls, t, 2, props=props)
    first = sim.step(seq, walls, t, props=props)
    second = sim.step(torch.cat([seq[:, 1:], first[:, None]], 1), walls, t + 0.0025, props=props)
    torch.testing.assert_close(two, torch.stack([first, second]), rtol=0, atol=0, equal_nan=True)


def test_a_model_with_the_options_refuses_to_run_without_them(hopper):
    traj, seq, present, t = hopper
    walls = WallSet(traj.scene)
    radius_model = _model(radius_feature=True)
    friction_model = _model(material_features=["friction"])
    for sim, option in (
        (radius_model, r"model.radius_feature=true"),
        (friction_model, r"model.material_features=\['friction'\]"),
    ):
        for call in (
            lambda s=sim: s.build_graph(seq, walls, t),
            lambda s=sim: s.predict_acceleration(seq, walls, t),
            lambda s=sim: s.step(seq, walls, t),
            lambda s=sim: s.rollout(seq, walls, t, 1),
        ):
            with pytest.raises(InputError, match=rf"{option}.*ParticleProps.of\(trajectory\)"):
                call()
    with pytest.raises(InputError, match=r"props: \d+ radii for \d+ particles"):
        radius_model.build_graph(seq, walls, t, props=_props(traj, present)[1:])
    with pytest.raises(InputError, match="needs the scene's materials"):
        friction_model.build_graph(seq, walls, t, props=ParticleProps(torch.ones(len(seq))))
    with pytest.raises(InputError, match=r"materials\.density: expected a positive"):
        _model(material_features=["density"]).build_graph(
            seq, walls, t, props=_props(traj, present, density=0.0)
        )


# -- training: windows, push-forward, unrolled ---------------------------------------------------


@pytest.fixture(scope="module")
def polydisperse():
    """The bundled hopper with a distinct radius per particle (1-2 mm)."""
    traj = read_trajectory(sample_files("hopper", "train")[0])
    radii = np.linspace(1e-3, 2e-3, traj.num_particles).astype(np.float32)
    return dataclasses.replace(traj, radii=radii)


def test_windows_carry_their_particles_properties(polydisperse):
    ds = WindowDataset([polydisperse], 5, 2)
    sim = _model(radius_feature=True, material_features=["friction"], dt=2 * polydisperse.frame_dt)
    for item in (0, len(ds) - 1):
        w = ds[item]
        _, t = w.index
        keep = polydisperse.present[np.arange(t - 10, t + 3, 2)].all(axis=0)
        assert torch.equal(w.props.radius, torch.from_numpy(polydisperse.radii[keep]))
        assert w.props.materials == polydisperse.scene.materials
        graph = _Collate(sim, 0.0, 0)([w])
        real = ~graph.is_wall
        torch.testing.assert_close(graph.x[real, -2], w.props.radius / CUTOFF, rtol=1e-6, atol=0)
        assert (graph.x[~real, -2] == 0).all() and (graph.x[:, -1] == 0.5).all()


def _last_window_with_many(ds: WindowDataset) -> int:
    return max(range(0, len(ds), 10), key=lambda i: ds[i].pos_seq.shape[0])


def _drop_the_largest(sim, calls):
    """A fake ``predict_acceleration`` that records its inputs and sends the largest particle
    a metre down within one step (below the outflow), every other one at rest."""
    dt = float(sim.dt)

    def predict(pos_seq, walls, time, neighbours=None, ids=None, props=None, frame=None):
        assert props is not None and len(props) == pos_seq.shape[0]
        calls.append((pos_seq.detach().clone(), props))
        acc = torch.zeros(pos_seq.shape[0], 3)
        acc[int(props.radius.argmax()), 2] = -1.0 / dt**2
        return acc

    return predict


def _rows_in(window_seq, seq) -> list[int]:
    """The window row of each row of a later ``seq`` (its oldest input = the window's second)."""
    ref = window_seq[:, 1].double()
    return [int(torch.nonzero((ref == row).all(1))[0, 0]) for row in seq[:, 0].double()]


def test_push_forward_keeps_the_properties_of_the_particles_it_keeps(polydisperse, monkeypatch):
    sim = _model(radius_feature=True, dt=2 * polydisperse.frame_dt)
    ds = WindowDataset([polydisperse], 5, 2, extra_steps=1)
    window = ds[_last_window_with_many(ds)]
    calls, built = [], []
    monkeypatch.setattr(sim, "predict_acceleration", _drop_the_largest(sim, calls))
    build_graph = sim.build_graph
    monkeypatch.setattr(
        sim,
        "build_graph",
        lambda seq, *a, **k: built.append((seq, k["props"])) or build_graph(seq, *a, **k),
    )
    pushed = PushForward(max_steps=1).pushed(sim, _Collate(sim, 0.0, 0)([window]), 1)
    seq, props = built[-1]
    assert len(props) == seq.shape[0] == window.pos_seq.shape[0] - 1  # the largest left
    rows = _rows_in(window.pos_seq, seq)
    assert torch.equal(props.radius, window.props.radius[rows])
    assert float(window.props.radius.max()) not in props.radius.tolist()
    real = ~pushed.is_wall
    torch.testing.assert_close(pushed.x[real, -1], props.radius / CUTOFF, rtol=1e-6, atol=0)


def test_unrolled_keeps_the_properties_of_the_particles_it_keeps(polydisperse, monkeypatch):
    sim = _model(radius_feature=True, dt=2 * polydisperse.frame_dt)
    ds = WindowDataset([polydisperse], 5, 2, extra_steps=1)
    window = ds[_last_window_with_many(ds)]
    calls = []
    monkeypatch.setattr(sim, "predict_acceleration", _drop_the_largest(sim, calls))
    Unrolled(steps=2).loss(sim, _Collate(sim, 0.0, 0)([window]), torch.Generator())
    assert len(calls) == 2
    assert torch.equal(calls[0][1].radius, window.props.radius)
    seq, props = calls[1]
    assert len(props) == window.pos_seq.shape[0] - 1
    assert torch.equal(props.radius, window.props.radius[_rows_in(window.pos_seq, seq)])


def test_a_tiny_run_with_the_options_trains_checkpoints_and_rolls_out(tmp_path):
    from granular_pyg.train import train

    cfg = compose(
        "train",
        [
            "model.radius_feature=true",
            "model.material_features=[friction,rolling_friction,restitution]",
            "model.latent=16",
            "data.batch_size=1",
            "data.frames_per_step=8",
            "data.train_samples_per_epoch=2",
            "data.val_samples=1",
            "trainer.max_steps=2",
            "trainer.max_epochs=1",
            "rollout_validation.every_n_epochs=1",  # the validation rollout takes them too
            "rollout_validation.steps=2",
        ],
    )
    train(cfg, out_dir=tmp_path)
    ckpt = tmp_path / "checkpoints" / "last.ckpt"
    sim, config = load_simulator(ckpt)
    assert config["model"]["radius_feature"] is True
    assert sim.radius_feature and sim.material_features == (
        "friction", "rolling_friction", "restitution",
    )  # fmt: skip
    truth = read_trajectory(sample_files("hopper", "test")[0])
    pred = rollout_trajectory(sim, truth, steps=2, progress=False)
    assert pred.num_frames == sim.history + 1 + 2
    assert np.isfinite(pred.positions[-1]).all(axis=1).any()
    seq = torch.from_numpy(truth.positions[: 6 * 8 : 8]).permute(1, 0, 2).contiguous()
    with pytest.raises(
        InputError, match=r"model\.radius_feature=true and model\.material_features"
    ):
        sim.step(seq, WallSet(truth.scene), float(truth.times[40]))
    # the properties change the prediction of the loaded model
    other = dataclasses.replace(truth, radii=np.full_like(truth.radii, 1e-3))
    moved = rollout_trajectory(sim, other, steps=1, progress=False)
    assert not np.allclose(
        pred.positions[sim.history + 1], moved.positions[sim.history + 1], equal_nan=True
    )


def test_the_contact_column_alone_adds_no_node_columns(hopper):
    """contact_feature without radius or material inputs: an edge column, no node column."""
    traj, seq, present, t = hopper
    sim = _model(contact_feature=True)
    graph = sim.build_graph(seq, WallSet(traj.scene), t, props=_props(traj, present))
    assert graph.x.shape[1] == BASE_WIDTH and graph.edge_attr.shape[1] == 5
