"""The physics' symmetries: turning a scene about gravity, mirroring it or re-meshing its walls
changes nothing but the frame. Property tests on real bundled trajectories, every wall variant."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from granular_pyg.geometry import (
    horizontal_frame,
    horizontally_isotropic,
    random_horizontal_frame,
    surface_patches,
)
from granular_pyg.io import read_trajectory
from granular_pyg.nn import HorizontalEquivariantProcessor, Processor
from granular_pyg.samples import sample_files
from granular_pyg.scenes import WallSet
from granular_pyg.scenes.redescribe import subdivided_scene, turned_scene
from granular_pyg.simulator import LearnedSimulator, ParticleProps

FRAMES = [
    horizontal_frame(37.0),
    horizontal_frame(90.0),
    horizontal_frame(0.0, mirror=True),
    horizontal_frame(211.0, mirror=True),
]


def _window(kind: str, frame: int):
    traj = read_trajectory(sample_files(kind)[-1])
    window = torch.from_numpy(traj.positions[frame - 5 : frame + 1]).permute(1, 0, 2).double()
    present = torch.isfinite(window).all(2).all(1)
    return traj, window[present].contiguous(), float(traj.times[frame]), present


def _sim(
    processor: str,
    normals: str,
    wall_nodes: str = "patch",
    dtype=torch.float64,
    sleep: bool = False,
):
    torch.manual_seed(3)
    proc = (
        HorizontalEquivariantProcessor(latent=24, num_steps=2, channels=6, wall_sum=True)
        if processor == "equivariant"
        else Processor(latent=24, num_steps=2, aggr="mean")
    )
    sim = LearnedSimulator(
        proc,
        radius=0.0075,
        normals=normals,
        latent=24,
        dt=0.005,
        contact_feature=True,
        radius_feature=True,
        wall_nodes=wall_nodes,
        sleep=sleep,
    )
    sim.set_normalization([0.01, -0.02, -0.2], [0.1, 0.12, 0.3], [0.3, 0.1, -9.8], [5.0, 4.0, 8.0])
    return sim.to(dtype).eval()


def _acc(sim, scene, seq, t, traj, present) -> torch.Tensor:
    props = ParticleProps(torch.from_numpy(traj.radii).double()[present])
    with torch.no_grad():
        return sim.predict_acceleration(seq, WallSet(scene), t, props=props).double()


@pytest.mark.parametrize("normals", ["none", "single", "both"])
@pytest.mark.parametrize("kind,frame", [("drum", 40), ("hopper", 30)])
def test_equivariant_processor_turns_and_mirrors_with_the_scene(kind, frame, normals):
    """A turn about z and/or a mirror of the scene (walls, their motion, positions) gives the
    turned/mirrored acceleration to 1e-5 in float64, for V1, V2 and V3. V2's normal follows the
    winding: it holds because a mirrored scene is re-wound (turned_scene keeps every wall's
    sides), see test_v2_mirror_without_rewinding_is_another_wall."""
    traj, seq, t, present = _window(kind, frame)
    sim = _sim("equivariant", normals)
    acc = _acc(sim, traj.scene, seq, t, traj, present)
    scale = acc.abs().max()
    for q in FRAMES:
        moved = _acc(sim, turned_scene(traj.scene, q), seq @ q.T, t, traj, present)
        assert torch.allclose(moved, acc @ q.T, atol=1e-5 * float(scale), rtol=0), q


def test_v2_mirror_without_rewinding_is_another_wall():
    """V2 reads the winding: mirroring the vertices but keeping the vertex order flips every
    normal, which V2 sees as the other side of the wall (V3 does not care)."""
    traj, seq, t, present = _window("hopper", 30)
    q = horizontal_frame(0.0, mirror=True)
    rewound = turned_scene(traj.scene, q)
    kept = turned_scene(traj.scene, q)
    for wall in kept.walls:
        wall.faces = wall.faces[:, ::-1].copy()  # undo the rewinding
    for normals, differs in (("single", True), ("both", False)):
        sim = _sim("equivariant", normals)
        a = _acc(sim, rewound, seq @ q.T, t, traj, present)
        b = _acc(sim, kept, seq @ q.T, t, traj, present)
        assert (not torch.allclose(a, b, atol=1e-8)) == differs


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
@pytest.mark.parametrize("normals", ["single", "both"])
def test_frame_argument_equals_the_turned_scene(processor, normals):
    """Training's augmentation (features built in a frame Q) is exactly the turned scene: the
    network sees the same inputs, for any processor, so Q a(frame=Q) = a(turned scene)."""
    traj, seq, t, present = _window("drum", 40)
    sim = _sim(processor, normals)
    props = ParticleProps(torch.from_numpy(traj.radii).double()[present])
    walls = WallSet(traj.scene)
    for q in FRAMES:
        with torch.no_grad():
            in_frame = sim.predict_acceleration(seq, walls, t, props=props, frame=q).double()
        moved = _acc(sim, turned_scene(traj.scene, q), seq @ q.T, t, traj, present)
        assert torch.allclose(moved, in_frame @ q.T, atol=1e-6 * float(moved.abs().max()))


def test_plain_processor_is_not_equivariant_without_data():
    """The check has teeth: an untrained BGNN with anisotropic statistics changes its answer
    when the scene turns (it must learn the symmetry from augmented data)."""
    traj, seq, t, present = _window("drum", 40)
    sim = _sim("bgnn", "both")
    q = horizontal_frame(90.0)
    acc = _acc(sim, traj.scene, seq, t, traj, present)
    moved = _acc(sim, turned_scene(traj.scene, q), seq @ q.T, t, traj, present)
    assert not torch.allclose(moved, acc @ q.T, atol=1e-3 * float(acc.abs().max()))


@pytest.mark.parametrize("processor", ["bgnn", "equivariant"])
@pytest.mark.parametrize("kind,frame", [("drum", 40), ("hopper", 30)])
def test_patch_wall_nodes_ignore_how_walls_were_triangulated(processor, kind, frame):
    """Every wall triangle split in 4 and in 16 (the same surfaces): with a wall node per
    surface patch the prediction is unchanged (1e-6); with one per triangle it changes."""
    traj, seq, t, present = _window(kind, frame)
    for wall_nodes, same in (("patch", True), ("triangle", False)):
        sim = _sim(processor, "both", wall_nodes)
        acc = _acc(sim, traj.scene, seq, t, traj, present)
        for times in (1, 2):
            finer = _acc(sim, subdivided_scene(traj.scene, times), seq, t, traj, present)
            close = torch.allclose(finer, acc, atol=1e-6 * float(acc.abs().max()), rtol=0)
            assert close == same, (wall_nodes, times)


def test_equivariant_model_float32_stays_close_to_float64():
    """Where precision holds: the float32 equivariant model matches float64 to 1e-4 of the
    acceleration scale on a turned drum, so its symmetry holds to that in float32."""
    traj, seq, t, present = _window("drum", 40)
    sim64 = _sim("equivariant", "both")
    sim32 = _sim("equivariant", "both", dtype=torch.float32)
    q = horizontal_frame(45.0)
    a64 = _acc(sim64, traj.scene, seq, t, traj, present)
    a32 = _acc(sim32, turned_scene(traj.scene, q), seq @ q.T, t, traj, present)
    assert torch.allclose(a32, a64 @ q.T, atol=1e-4 * float(a64.abs().max()), rtol=0)


def test_horizontally_isotropic_statistics():
    mean, std = horizontally_isotropic([3.0, -4.0, 1.0], [0.0, 0.0, 2.0])
    np.testing.assert_allclose(mean, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(std, [np.sqrt(12.5), np.sqrt(12.5), 2.0])


def test_random_frames_are_seeded_turns_about_z():
    q1 = random_horizontal_frame(torch.Generator().manual_seed(5))
    q2 = random_horizontal_frame(torch.Generator().manual_seed(5))
    assert torch.equal(q1, q2)
    dets = []
    for seed in range(40):
        q = random_horizontal_frame(torch.Generator().manual_seed(seed))
        assert torch.allclose(q @ q.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
        assert torch.equal(q[2], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
        dets.append(float(torch.linalg.det(q)))
    assert min(dets) == pytest.approx(-1.0) and max(dets) == pytest.approx(1.0)


def test_surface_patches_tiny_cases():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    two = np.array([[0, 1, 2], [0, 2, 3]])
    assert surface_patches(square, two).tolist() == [0, 0]
    assert surface_patches(square, two[:, ::-1]).tolist() == [0, 0]  # winding does not matter
    # A cube: 6 faces of 2 triangles, 90 degrees apart: 6 patches of 2.
    import trimesh

    cube = trimesh.creation.box()
    ids = surface_patches(cube.vertices, cube.faces)
    assert ids.max() + 1 == 6 and np.bincount(ids).tolist() == [2] * 6
    # A cylinder of 48 sections (7.5 degrees apart): shell and two caps.
    cyl = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=48)
    assert surface_patches(cyl.vertices, cyl.faces).max() + 1 == 3
    # Split in four: the same patches.
    scene = subdivided_scene(__import__("granular_pyg").scenes.make_drum(), 1)
    assert WallSet(scene).num_patches == 3


def test_turned_scene_turns_normals_and_motion():
    """Turned walls keep their sides (a mirror re-winds them) and a rotation axis flips under a
    mirror (a pseudovector), so a mirrored drum turns the other way as seen in the mirror."""
    from granular_pyg.scenes import make_drum

    drum = make_drum()
    for q in FRAMES:
        moved = turned_scene(drum, q)
        a, b = WallSet(drum), WallSet(moved)
        assert torch.allclose(b.normals[0], a.normals[0] @ q.T, atol=1e-12)
        axis = np.asarray(moved.walls[0].motion.axis)
        np.testing.assert_allclose(
            axis, np.linalg.det(q.numpy()) * q.numpy() @ (0, 1, 0), atol=1e-12
        )
        # the wall velocity at a mirrored point is the mirrored velocity
        pts = torch.tensor([[0.0, 0.0, -0.045]], dtype=torch.float64)
        va = a.contacts(pts, 0.01, 0.5).velocity
        vb = b.contacts(pts @ q.T, 0.01, 0.5).velocity
        assert torch.allclose(vb.mean(0), va.mean(0) @ q.T, atol=1e-12)


def test_a_turned_or_mirrored_drum_that_reverses_keeps_its_reversal():
    """A drum that turns back at 0.3 s, turned about z or mirrored: its reversal times are
    kept, the wall's pose at every time is the turned pose, and the wall velocity at a
    turned point is the turned velocity before and after the reversal (the mirror flips the
    sense of both legs)."""
    from granular_pyg.scenes import make_drum

    drum = make_drum(spin_reverse=0.3)
    motion = drum.walls[0].motion
    assert tuple(motion.reverse_times) == (0.3,)
    pts = torch.tensor([[0.0, 0.0, -0.045], [0.03, 0.01, 0.02]], dtype=torch.float64)
    for q in FRAMES:
        moved = turned_scene(drum, q)
        assert tuple(moved.walls[0].motion.reverse_times) == (0.3,)
        a, b = WallSet(drum), WallSet(moved)
        qn = q.numpy()
        for t in (0.1, 0.29, 0.31, 0.6):
            rot_a, trans_a = motion.pose(t)
            rot_b, trans_b = moved.walls[0].motion.pose(t)
            vertices, turned = drum.walls[0].vertices, moved.walls[0].vertices
            np.testing.assert_allclose(
                turned @ rot_b.T + trans_b,
                (vertices @ rot_a.T + trans_a) @ qn.T,
                atol=1e-12,
            )
            va = a.contacts(pts, 0.01, t).velocity
            vb = b.contacts(pts @ q.T, 0.01, t).velocity
            assert va.shape[0] > 0 and va.abs().max() > 1e-3
            assert torch.allclose(vb, va @ q.T, atol=1e-12), (q, t)
        # the reversal shows: the velocity at a point flips sign across it
        before = a.contacts(pts, 0.01, 0.29).velocity
        after = a.contacts(pts, 0.01, 0.31).velocity
        assert torch.allclose(after, -before, atol=1e-12)
