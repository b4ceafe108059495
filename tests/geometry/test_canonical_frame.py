"""The scene's own horizontal frame (``geometry.canonical_frame``): equivariant under turns
about gravity and mirrors, unchanged by re-meshing, exact surface integrals, and a model that is
not equivariant made so by it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from granular_pyg.geometry import canonical_frame, horizontal_frame
from granular_pyg.geometry.canonical_frame import _surface_moment
from granular_pyg.io import read_trajectory
from granular_pyg.nn import Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import Wall, WallMotion, WallSet
from granular_pyg.scenes.example_meshes import cone_hopper, silo
from granular_pyg.scenes.redescribe import subdivided_scene, turned_scene
from granular_pyg.simulator import LearnedSimulator, ParticleProps

FRAMES = [
    horizontal_frame(37.0).numpy(),
    horizontal_frame(90.0).numpy(),
    horizontal_frame(180.0).numpy(),
    horizontal_frame(0.0, mirror=True).numpy(),
    horizontal_frame(211.0, mirror=True).numpy(),
]


def _sample(kind: str):
    traj = read_trajectory(sample_files(kind)[-1])
    points = traj.positions[0]
    return traj, points[np.isfinite(points).all(1)]


def _mesh_walls(meshes: dict) -> list[Wall]:
    return [Wall(name, v, f) for name, (v, f) in meshes.items()]


def _omega_in_frame(q: np.ndarray, motion: WallMotion) -> np.ndarray:
    """The drum's angular velocity seen in frame ``q`` (a pseudovector: det(q) q omega)."""
    return np.linalg.det(q) * q @ (motion.omega * np.asarray(motion.axis))


@pytest.mark.parametrize("kind", ["hopper", "drum"])
def test_frame_turns_with_the_scene_and_ignores_the_mesh(kind):
    """The scene turned or mirrored by g has the frame Q g^T (so both copies look the same),
    and every wall triangle split in 4 or 16 leaves Q unchanged."""
    traj, points = _sample(kind)
    q = canonical_frame(traj.scene.walls, points)
    assert np.allclose(q @ q.T, np.eye(3), atol=1e-12) and np.allclose(q[2], [0, 0, 1])
    for g in FRAMES:
        moved = canonical_frame(turned_scene(traj.scene, g).walls, points @ g.T)
        assert np.allclose(moved, q @ g.T, atol=1e-9), g
    for times in (1, 2):
        remeshed = canonical_frame(subdivided_scene(traj.scene, times).walls, points)
        assert np.allclose(remeshed, q, atol=1e-9), times


def test_a_drum_is_seen_turning_about_plus_e2_either_way_it_turns():
    """The bundled drum (axis y, omega > 0: the training sets' sense) is seen as it is or
    mirrored along its own axis; turning the other way, its mirror image: in the frame the
    drum always turns about +e2."""
    traj, points = _sample("drum")
    (drum,) = [w for w in traj.scene.walls if w.motion.kind == "rotation"]
    q = canonical_frame(traj.scene.walls, points)
    assert np.allclose(np.abs(q), np.eye(3), atol=1e-9)  # identity or y -> -y
    assert _omega_in_frame(q, drum.motion)[1] > 0
    reverse = dataclasses.replace(drum.motion, omega=-drum.motion.omega)
    walls = [dataclasses.replace(w, motion=reverse) if w is drum else w for w in traj.scene.walls]
    q_rev = canonical_frame(walls, points)
    assert np.linalg.det(q_rev) == pytest.approx(-np.linalg.det(q))
    assert _omega_in_frame(q_rev, reverse)[1] > 0


def test_a_wedge_hopper_keeps_its_inclined_walls_facing_x():
    """The wedge's inclined walls face +-x, the training sets' way: e1 is +-x."""
    traj, points = _sample("hopper")
    q = canonical_frame(traj.scene.walls, points)
    assert np.allclose(np.abs(q), np.eye(3), atol=1e-9)


def test_an_axisymmetric_cone_falls_to_the_bed_and_a_silo_to_its_outlet():
    """A cone's walls decide nothing: the bed's spread and lean decide, equivariantly; without
    a bed the world frame is kept. The silo's off-axis outlet decides by itself: e1 along it."""
    walls = _mesh_walls(cone_hopper())
    assert np.allclose(canonical_frame(walls), np.eye(3))
    rng = np.random.default_rng(4)
    bed = rng.normal(size=(400, 3)) * [0.02, 0.01, 0.01] + [0.003, -0.002, 0.05]
    q = canonical_frame(walls, bed)
    for g in FRAMES:
        moved = [Wall(w.name, w.vertices @ g.T, w.faces) for w in walls]
        assert np.allclose(canonical_frame(moved, bed @ g.T), q @ g.T, atol=1e-9)
    q_silo = canonical_frame(_mesh_walls(silo()))
    assert abs(q_silo[0, 0]) == pytest.approx(1.0)


def test_no_surface_or_a_vertical_axis_decides_nothing_by_itself():
    """Walls of zero area keep the world frame; a wall turning about the vertical (a mixer) is
    not a drum: the static rules decide, and a flat floor alone decides nothing."""
    flat = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    assert np.array_equal(canonical_frame([Wall("line", flat, np.array([[0, 1, 2]]))]), np.eye(3))
    square = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    spin = WallMotion(kind="rotation", axis=(0.0, 0.0, 1.0), omega=3.0)
    floor = Wall("floor", square, np.array([[0, 1, 2], [0, 2, 3]]), spin)
    assert np.array_equal(canonical_frame([floor]), np.eye(3))


def test_surface_moments_match_dense_sampling():
    """The exact integrals of s, s^2, s^3 over random triangles against the midpoint rule on
    each triangle split 4^6 times (brute force)."""
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(5, 3, 3))
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    direction = np.array([0.6, -0.8, 0.0])
    fine = tri
    for _ in range(6):
        a, b, c = fine[:, 0], fine[:, 1], fine[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        fine = np.concatenate(
            [np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
        )
    fine_area = 0.5 * np.linalg.norm(
        np.cross(fine[:, 1] - fine[:, 0], fine[:, 2] - fine[:, 0]), axis=1
    )
    s_mid = fine.mean(1) @ direction
    for order in (1, 2, 3):
        exact = _surface_moment(tri @ direction, area, order)
        dense = float(np.sum(fine_area * s_mid**order))
        assert exact == pytest.approx(dense, rel=1e-3), order
    # a single triangle, s = 1 at one vertex: integral s^3 dA = A / 10
    one = np.array([[1.0, 0.0, 0.0]])
    assert _surface_moment(one, np.array([2.0]), 3) == pytest.approx(0.2)


def _bgnn(canonical: bool) -> LearnedSimulator:
    torch.manual_seed(5)
    sim = LearnedSimulator(
        Processor(latent=24, num_steps=2, aggr="mean"),
        radius=0.0075,
        latent=24,
        dt=0.005,
        radius_feature=True,
        wall_nodes="patch",
        canonical_frame=canonical,
    )
    sim.set_normalization([0.01, -0.02, -0.2], [0.1, 0.12, 0.3], [0.3, 0.1, -9.8], [5.0, 4.0, 8.0])
    return sim.double().eval()


@pytest.mark.parametrize("kind,frame", [("drum", 40), ("hopper", 30)])
def test_a_plain_model_in_the_scene_frame_turns_and_mirrors_with_the_scene(kind, frame):
    """With canonical_frame, a processor that is not equivariant gives the turned/mirrored
    step for a turned/mirrored scene, to 1e-9 in float64 (without it, it does not)."""
    traj = read_trajectory(sample_files(kind)[-1])
    window = torch.from_numpy(traj.positions[frame - 5 : frame + 1]).permute(1, 0, 2).double()
    present = torch.isfinite(window).all(2).all(1)
    seq, t = window[present].contiguous(), float(traj.times[frame])
    props = ParticleProps(torch.from_numpy(traj.radii).double()[present])
    for canonical in (True, False):
        sim = _bgnn(canonical)
        nxt = sim.step(seq, WallSet(traj.scene), t, props=props)
        errors = []
        for g in FRAMES:
            gt = torch.from_numpy(g)
            moved = sim.step(seq @ gt.T, WallSet(turned_scene(traj.scene, g)), t, props=props)
            errors.append(float((moved - nxt @ gt.T).abs().max()))
        if canonical:
            assert max(errors) < 1e-9, errors
        else:
            assert max(errors) > 1e-6, errors


def test_canonical_frame_and_augmentation_refuse_each_other(tmp_path):
    """Training a model in the scene's frame and in random frames at once is refused, with
    the fix named."""
    from granular_pyg.errors import InputError
    from granular_pyg.training import TrajectoryDataModule

    data = TrajectoryDataModule(sample="hopper", history=5, frames_per_step=8, augment=True)
    with pytest.raises(InputError, match=r"data\.augment=false"):
        data.attach(_bgnn(True).float())


def test_training_sees_each_window_in_its_scene_frame():
    """A model with canonical_frame trains on each window in the frame its rollouts use:
    the window's frame is the scene's own, and the batch's inputs are those of that frame."""
    from tests.training.one_batch import model_objective_batch

    sim, _, batch = model_objective_batch(
        ["model.latent=16", "model.canonical_frame=true", "data.augment=false"]
    )
    for window in batch.windows:
        expected = sim.scene_frame(window.walls, window.pos_seq[:, -1])
        assert window.frame is not None and torch.equal(window.frame, expected)
