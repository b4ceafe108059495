"""``model.rest_gate``: the acceleration times ``relu(1 + g)``. Open at initialisation (the model
without it, exactly), closed it holds a bed to the bit, equivariant either way; fine-tuning may
switch it on; ``data.clean_share`` gives it windows without noise, where its own loss (labels
from the clean truth, a hinge on ``g``) teaches it to shut on a bed at rest."""

from __future__ import annotations

import pytest
import torch

from granular_pyg.checkpoint.fine_tune import load_initial_weights, with_open_gate
from granular_pyg.data.windows import WindowDataset
from granular_pyg.errors import InputError
from granular_pyg.geometry import horizontal_frame
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.nn.rest_gate import (
    GATE_GAIN,
    GATE_MARGIN,
    gate_hinge,
    gate_labels,
    gated,
)
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.scenes.redescribe import turned_scene
from granular_pyg.simulator import LearnedSimulator, ParticleProps
from granular_pyg.training.data_module import (
    REST_SPEED,
    EpochSampler,
    TrajectoryDataModule,
    _Collate,
)
from granular_pyg.training.objectives import OneStep
from tests.test_symmetries import _sim, _window


def _bed():
    """The bundled hopper's settled bed (frame 0, lid closed) held: a history at rest, the
    trajectory, the time and the particle properties."""
    traj = read_trajectory(sample_files("hopper")[0])
    seq = torch.from_numpy(traj.positions[0]).double()[:, None].repeat(1, 6, 1)
    return traj, seq, float(traj.times[0]), ParticleProps.of(traj)


def _flow(frame: int):
    """The bundled hopper's flow ending at ``frame`` (:func:`tests.test_symmetries._window`):
    the trajectory, the present particles' ``[N, 6, 3]`` positions, the time and their
    properties."""
    traj, seq, t, present = _window("hopper", frame)
    return traj, seq, t, ParticleProps.of(traj)[present]


def _gate_layer(sim):
    return sim.model.gate.mlp[-1]


def test_gated_tiny_cases():
    acc = torch.tensor([[1.0, -2.0, 3.0], [4.0, 5.0, -6.0], [1.0, 1.0, 1.0]])
    logits = torch.tensor([[0.0], [-1.0], [-0.5]])
    assert torch.equal(gated(acc, logits), torch.tensor([[1.0, -2.0, 3.0], [0, 0, 0], [0.5] * 3]))


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
def test_an_open_gate_is_the_model_without_it(processor):
    plain, with_gate = _sim(processor, "both"), _sim(processor, "both", rest_gate=True)
    missing, unexpected = with_gate.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("model.gate.") for k in missing)
    traj, seq, t, props = _flow(30)
    with torch.no_grad():
        a = plain.predict_acceleration(seq, WallSet(traj.scene), t, props=props)
        b = with_gate.predict_acceleration(seq, WallSet(traj.scene), t, props=props)
    assert torch.equal(a, b)


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
def test_a_closed_gate_holds_a_bed_at_rest_to_the_bit(processor):
    sim = _sim(processor, "both", rest_gate=True)
    torch.nn.init.constant_(_gate_layer(sim).bias, -3.0)  # g = -3 everywhere: closed
    traj, seq, t, props = _bed()
    walls = WallSet(traj.scene)
    start = seq.clone()
    for k in range(10):
        nxt = sim.step(seq, walls, t + k * float(sim.dt), props=props)
        seq = torch.cat([seq[:, 1:], nxt[:, None]], dim=1)
    assert torch.equal(seq, start)
    # a closed gate stops the acceleration, not the motion: a bed moving at 1 mm/s keeps it
    v = torch.tensor([0.0, 0.0, -1e-3]) * float(sim.dt)
    moving = start + torch.arange(6).double()[None, :, None] * v
    nxt = sim.step(moving, walls, t, props=props)
    torch.testing.assert_close(nxt, moving[:, -1] + v, rtol=0, atol=1e-15)


@pytest.mark.parametrize("normals", ["none", "single", "both"])
def test_a_gated_equivariant_model_turns_and_mirrors_with_the_scene(normals):
    sim = _sim("equivariant", normals, rest_gate=True)
    layer = _gate_layer(sim)
    torch.manual_seed(5)
    # a gate that varies from particle to particle, logits about -0.5 +- 1
    torch.nn.init.normal_(layer.weight, std=1.0 / GATE_GAIN)
    torch.nn.init.constant_(layer.bias, -0.5 / GATE_GAIN)
    traj, seq, t, props = _flow(30)
    with torch.no_grad():
        acc = sim.predict_acceleration(seq, WallSet(traj.scene), t, props=props)
        for q in (horizontal_frame(37.0), horizontal_frame(211.0, mirror=True)):
            moved = sim.predict_acceleration(
                seq @ q.T, WallSet(turned_scene(traj.scene, q)), t, props=props
            )
            assert torch.allclose(moved, acc @ q.T, atol=1e-5 * float(acc.abs().max()), rtol=0)


def test_a_shut_gate_acts_outside_training_passes_only():
    """In a training pass the acceleration is the network's own (its loss reaches it where the
    gate is shut: a release starts there); in evaluation, or without autograd, it is gated."""
    sim = _sim("equivariant", "both", rest_gate=True)
    torch.nn.init.constant_(_gate_layer(sim).bias, -3.0)  # shut everywhere
    traj, seq, t, props = _flow(30)
    walls = WallSet(traj.scene)
    sim.train()
    with torch.no_grad():
        assert not sim.predict_acceleration(seq, walls, t, props=props).any()
    acc = sim.predict_acceleration(seq, walls, t, props=props)
    assert acc.abs().min() > 0  # the network's own acceleration, not gated
    acc.square().sum().backward()
    grads = [p.grad for n, p in sim.model.named_parameters() if n.startswith("decoder.")]
    assert all(g is not None and g.abs().sum() > 0 for g in grads)
    gate_grad = _gate_layer(sim).bias.grad  # the acceleration's loss does not reach the gate
    assert gate_grad is None or not gate_grad.any()
    sim.eval()
    assert not sim.predict_acceleration(seq, walls, t, props=props).any()


def test_fine_tuning_switches_the_gate_on_open():
    plain, with_gate = _sim("equivariant", "both"), _sim("equivariant", "both", rest_gate=True)
    torch.nn.init.normal_(with_gate.model.decoder[-1].weight)  # differs until loaded
    state = {f"sim.{k}": v for k, v in plain.state_dict().items()}
    load_initial_weights(with_gate, {"state_dict": with_open_gate(state, 24, 2)})
    assert with_open_gate(state, 24, 2).keys() - state.keys()  # the gate was added
    gated_state = {f"sim.{k}": v for k, v in with_gate.state_dict().items()}
    assert with_open_gate(gated_state, 24, 2) is gated_state  # a gate there is kept
    assert torch.equal(
        _gate_layer(with_gate).weight, torch.zeros_like(_gate_layer(with_gate).weight)
    )
    traj, seq, t, props = _bed()
    with torch.no_grad():
        a = plain.predict_acceleration(seq, WallSet(traj.scene), t, props=props)
        b = with_gate.predict_acceleration(seq, WallSet(traj.scene), t, props=props)
    assert torch.equal(a, b)


def test_clean_share_leaves_a_share_of_windows_without_noise():
    sim = LearnedSimulator(Processor(latent=16, num_steps=2), radius=0.0075, latent=16, dt=0.0025)
    sim.set_normalization([0.0, 0.0, -0.2], [0.1, 0.1, 0.3], [0.0, 0.0, -9.8], [5.0, 5.0, 8.0])
    data = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1)
    windows = [data[(epoch, (7 * epoch) % len(data))] for epoch in range(40)]
    clean = _Collate(sim, 0.0, 0)
    noisy = _Collate(sim, 1e-4, 0, offset_std=1e-4)
    half = _Collate(sim, 1e-4, 0, offset_std=1e-4, clean_share=0.5)
    always = _Collate(sim, 1e-4, 0, offset_std=1e-4, clean_share=1.0)
    kinds = []
    for w in windows:
        y_clean, y_noisy = clean([w]).y, noisy([w]).y
        assert not torch.equal(y_clean, y_noisy)
        assert torch.equal(always([w]).y, y_clean)
        y_half = half([w]).y
        # a window is either clean or noised exactly as without the option
        assert torch.equal(y_half, y_clean) or torch.equal(y_half, y_noisy)
        kinds.append(torch.equal(y_half, y_clean))
    assert 8 <= sum(kinds) <= 32  # 40 windows, half clean: binomial, 5.7 sigma either side


def test_gate_labels_tiny_cases():
    rest = torch.tensor([True, True, False, True, False])
    step = torch.tensor([[0, 0, 1e-6], [0, 2e-5, 0], [0, 0, 0], [float("nan")] * 3, [3e-5, 0, 0]])
    # at rest in history and target: shut; target moving: open; lost (NaN) or only slowing: 0
    clean = gate_labels(rest, step.double(), 1e-5, clean=True)
    assert clean.tolist() == [-1.0, 1.0, 0.0, 0.0, 1.0]
    # noised inputs are not at rest: nobody is shut
    noisy = gate_labels(rest, step.double(), 1e-5, clean=False)
    assert noisy.tolist() == [0, 1, 0, 0, 1]


def test_gate_hinge_tiny_cases():
    logits = torch.tensor([[-2.0], [-1.0], [0.5], [-0.25], [3.0]])
    labels = torch.tensor([-1.0, -1.0, 1.0, 3.0, 0.0])
    # shut: relu(g + 1 + margin) = 0 and margin; open: |g| = 0.5 and 3 x 0.25; unlabelled: 0
    expected = (0.0 + GATE_MARGIN + 0.5 + 0.75 + 0.0) / 5
    assert gate_hinge(logits, labels).item() == pytest.approx(expected, abs=1e-7)
    assert gate_hinge(logits, torch.zeros(5)).item() == 0.0


def _bed_windows():
    """Windows of the bundled hopper's first frames, its bed at rest on the closed lid."""
    data = WindowDataset(sample_files("hopper")[:1], history=5, frames_per_step=1)
    return [data[(0, i)] for i in range(3)]


def test_collate_labels_a_bed_at_rest_shut_only_without_noise():
    sim = _sim("equivariant", "both", rest_gate=True)
    windows = _bed_windows()
    clean = _Collate(sim, 1e-4, 0, clean_share=1.0)(windows)
    noisy = _Collate(sim, 1e-4, 0)(windows)
    assert (clean.gate_label == -1).float().mean() > 0.5  # most of the settled bed
    assert not (noisy.gate_label == -1).any()
    # each shut particle moves less than the rest speed over the step, in the truth
    sizes = [len(w.pos_seq) for w in windows]
    for w, labels in zip(windows, clean.gate_label.split(sizes), strict=True):
        step = (w.target_pos - w.pos_seq[:, -1]).norm(dim=1)
        assert (step[labels == -1] < REST_SPEED * float(sim.dt)).all()


def test_the_gate_loss_shuts_the_gate_on_a_bed_at_rest():
    """Through the acceleration alone a bed at rest barely moves the gate (its gradient scales
    with that acceleration); with its own loss, a few optimiser steps shut it."""
    sim = _sim("equivariant", "both", rest_gate=True)
    batch = _Collate(sim, 1e-4, 0, clean_share=1.0)(_bed_windows())
    shut = batch.gate_label == -1
    opt = torch.optim.Adam(sim.model.gate.parameters(), lr=1e-2)
    for _ in range(60):
        opt.zero_grad()
        OneStep().loss(sim, batch, torch.Generator()).backward()
        opt.step()
    with torch.no_grad():
        out = sim._network_output(batch)
    closed = out[:, 3] <= -1.0
    assert closed[shut].float().mean() > 0.95
    assert not sim._gated_acceleration(out)[closed].any()  # exactly zero acceleration


def test_a_rest_gate_without_clean_windows_is_refused():
    data = TrajectoryDataModule(sample="hopper", noise_std=1e-4, clean_share=0.0)
    with pytest.raises(InputError, match=r"data\.clean_share"):
        data.attach(_sim("equivariant", "both", rest_gate=True))


def test_event_windows_hold_a_wall_event_and_event_share_draws_them():
    data = WindowDataset(sample_files("hopper")[:1], history=2, frames_per_step=1)
    dt = data.frame_dt
    events = data.event_windows()
    assert events  # the bundled hopper's lid is removed at 0.02 s
    for item in range(len(data)):
        i, t = data.index[item]
        time = float(data.trajs[i].times[t])
        assert bool(data.walls[i].changing(time - dt, time + dt)) == (item in events)
    plain = EpochSampler(len(data), 400, seed=3, shuffle=True)
    share = EpochSampler(len(data), 400, seed=3, shuffle=True, events=events, event_share=0.5)
    drawn = [w for _, w in share]
    assert drawn == [w for _, w in share]  # the same draws for the same (seed, epoch)
    from_events = sum(w in events for w in drawn) / len(drawn)
    base = sum(w in events for _, w in plain) / 400
    assert 0.4 < from_events - base * 0.5 < 0.6  # about half the draws swapped for events
