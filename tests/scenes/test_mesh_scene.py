"""Scenes from STL files: wall motions, size distributions and regions, the example meshes, and
tiny real LIGGGHTS runs of the three example scenes."""

from __future__ import annotations

import hashlib
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf
from scipy.spatial import ConvexHull

from granular_pyg.dem.liggghts import (
    check_wall_for_liggghts,
    find_liggghts,
    render_input,
    write_ascii_stl,
)
from granular_pyg.dem.simulate import simulate
from granular_pyg.errors import InputError
from granular_pyg.generate import plan_trajectories
from granular_pyg.io import Trajectory, read_trajectory, write_trajectory
from granular_pyg.scenes import (
    ParticleSpec,
    Scene,
    Wall,
    WallMotion,
    WallSet,
    check_insertion_region,
    inside_walls,
    make_drum,
    make_hopper,
    make_mesh_scene,
)
from granular_pyg.scenes import example_meshes as examples
from granular_pyg.scenes.containment import (
    inside_closed_surface,
    inside_convex_hull,
    is_closed_surface,
    walls_at,
)
from granular_pyg.scenes.mesh_scene import MESH_DIR, load_stl

REPO = Path(__file__).resolve().parents[2]
SAMPLES = REPO / "granular_pyg" / "samples"
CONFIGS = ("mesh_cone", "mesh_pyramid", "mesh_silo", "mesh_lifter_drum")


def _build(config: str, *overrides: str, **changes) -> Scene:
    """The scene of ``conf/scene/<config>.yaml`` with Hydra ``overrides`` and then ``changes``
    to its build keys."""
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("generate", overrides=[f"scene={config}", *overrides])
    params = OmegaConf.to_container(cfg.scene.build, resolve=True) | changes
    assert params.pop("_target_") == "granular_pyg.scenes.make_mesh_scene"
    return make_mesh_scene(**params)


# --- wall motions ---------------------------------------------------------------------------


def test_translation_starts_moves_and_stops():
    m = WallMotion("translation", velocity=(0.1, 0.0, -0.2), start_time=0.5, stop_time=1.5)
    for t, want in [
        (0.0, (0, 0, 0)),
        (0.5, (0, 0, 0)),
        (1.0, (0.05, 0, -0.1)),
        (2.0, (0.1, 0, -0.2)),
    ]:
        rot, shift = m.pose(t)
        np.testing.assert_array_equal(rot, np.eye(3))
        np.testing.assert_array_equal(shift, want)
    np.testing.assert_array_equal(m.linear_velocity(1.0), (0.1, 0.0, -0.2))
    np.testing.assert_array_equal(m.linear_velocity(0.25), 0.0)
    np.testing.assert_array_equal(m.linear_velocity(1.5), 0.0)  # stopped
    assert not m.active(0.4) and m.active(0.5) and not m.active(1.5)


def test_oscillation_is_a_sine_from_its_start():
    m = WallMotion("oscillation", amplitude=(0.002, 0.0, -0.001), period=0.4, start_time=0.1)
    np.testing.assert_array_equal(m.pose(0.05)[1], 0.0)
    np.testing.assert_allclose(m.pose(0.2)[1], (0.002, 0.0, -0.001), atol=1e-18)  # a quarter
    np.testing.assert_allclose(m.pose(0.3)[1], 0.0, atol=1e-18)
    np.testing.assert_allclose(m.pose(0.4)[1], (-0.002, 0.0, 0.001), atol=1e-18)
    rate = 2 * math.pi / 0.4
    np.testing.assert_allclose(m.linear_velocity(0.1), (0.002 * rate, 0.0, -0.001 * rate))
    np.testing.assert_allclose(m.linear_velocity(0.2), 0.0, atol=1e-17)
    stopped = WallMotion("oscillation", amplitude=(0.002, 0, 0), period=0.4, stop_time=0.1)
    np.testing.assert_array_equal(stopped.pose(5.0)[1], stopped.pose(0.1)[1])


def test_rotation_pose_is_bit_identical_to_the_rodrigues_formula():
    m = WallMotion(
        "rotation", axis=(0.0, 1.0, 0.0), origin=(0.01, 0.0, 0.02), omega=2.0, start_time=0.25
    )
    angle = 2.0 * (0.75 - 0.25)
    k = np.array([[0.0, -0.0, 1.0], [0.0, 0.0, -0.0], [-1.0, 0.0, 0.0]])
    want = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)
    rot, shift = m.pose(0.75)
    np.testing.assert_array_equal(rot, want)
    np.testing.assert_array_equal(shift, np.array([0.01, 0, 0.02]) - want @ [0.01, 0, 0.02])
    np.testing.assert_array_equal(m.pose(0.1)[0], np.eye(3))  # before its start
    points = np.array([[0.01, 0.0, 0.05]])
    np.testing.assert_allclose(m.point_velocities(points, 1.0), [[0.06, 0.0, 0.0]])


def test_a_reversed_rotation_turns_back_through_the_poses_it_came_from():
    m = WallMotion(
        "rotation",
        axis=(0.0, 0.0, 1.0),
        omega=1.5,
        start_time=0.1,
        stop_time=1.4,
        reverse_times=(0.5, 1.3),
    )
    forward = WallMotion("rotation", axis=(0.0, 0.0, 1.0), omega=1.5, start_time=0.1)
    assert m.angle(0.5) == pytest.approx(0.6) and m.angle(0.9) == pytest.approx(0.0)
    assert m.angle(1.3) == pytest.approx(-0.6) and m.angle(2.0) == pytest.approx(-0.45)
    for t in (0.3, 0.5):  # before the reversal: the plain rotation's poses, bit for bit
        np.testing.assert_array_equal(m.pose(t)[0], forward.pose(t)[0])
    np.testing.assert_allclose(m.pose(0.7)[0], forward.pose(0.3)[0], atol=1e-15)  # on the way back
    assert [m.angular_velocity(t) for t in (0.05, 0.4, 0.5, 1.35, 1.5)] == [0, 1.5, -1.5, 1.5, 0]
    points = np.array([[0.02, 0.0, 0.0]])
    np.testing.assert_allclose(m.point_velocities(points, 0.6), [[0.0, -0.03, 0.0]])
    assert Scene.from_dict(_moving_scene(walls=[_plate("p", m)]).to_dict()).walls[0].motion == m
    assert "reverse_times" not in forward.to_dict()  # files of motions that never reverse as before


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kind": "translation", "reverse_times": (0.5,)}, "only a rotation reverses"),
        ({"kind": "rotation", "start_time": 0.5, "reverse_times": (0.2,)}, "reverse_times"),
        ({"kind": "rotation", "reverse_times": (0.4, 0.3)}, "increasing"),
        ({"kind": "rotation", "stop_time": 1.0, "reverse_times": (1.2,)}, "stop_time"),
        ({"kind": "spin"}, "motion.kind"),
        ({"kind": "oscillation", "amplitude": (1, 0, 0)}, "motion.period"),
        ({"kind": "translation", "start_time": 1.0, "stop_time": 0.5}, "stop_time"),
        ({"kind": "translation", "start_time": -1.0}, "start_time"),
        ({"kind": "translation", "velocity": (1.0, 2.0)}, "motion.velocity"),
    ],
)
def test_bad_motions_are_named(kwargs, message):
    with pytest.raises(InputError, match=message):
        WallMotion(**kwargs)


def _plate(name: str, motion: WallMotion, removal_time=None, z: float = 0.0) -> Wall:
    v = np.array([[-0.02, -0.02, z], [0.02, -0.02, z], [0.02, 0.02, z], [-0.02, 0.02, z]])
    return Wall(name, v, np.array([[0, 1, 2], [0, 2, 3]]), motion, removal_time)


def _moving_scene(**kwargs) -> Scene:
    walls = [
        _plate(
            "floor",
            WallMotion("translation", velocity=(0, 0, 0.01), start_time=0.01, stop_time=0.03),
        ),
        _plate(
            "shaker",
            WallMotion("oscillation", amplitude=(0.001, 0, 0), period=0.02, start_time=0.0),
            removal_time=0.02,
            z=0.05,
        ),
    ]
    defaults = dict(
        name="plates",
        walls=walls,
        particles=ParticleSpec(10, 0.001, (-0.01, -0.01, 0.01), (0.01, 0.01, 0.03)),
        domain_lo=(-0.03, -0.03, -0.01),
        domain_hi=(0.03, 0.03, 0.06),
        duration=0.04,
        frame_dt=0.005,
        settle_time=0.01,
    )
    return Scene(**(defaults | kwargs))


def test_liggghts_script_starts_and_stops_motions_between_runs():
    script = render_input(_moving_scene(), seed=1).splitlines()
    runs = [(i, int(line.split()[1])) for i, line in enumerate(script) if line.startswith("run ")]
    assert [n for _, n in runs] == [500, 500, 500, 500, 500]  # settle, then 0.01/0.02/0.03 s
    at = {line: i for i, line in enumerate(script)}
    wiggle = (
        "fix move_shaker all move/mesh mesh wall_shaker wiggle amplitude 0.001 0.0 0.0 period 0.02"
    )
    linear = "fix move_floor all move/mesh mesh wall_floor linear 0.0 0.0 0.01"
    assert runs[0][0] < at[wiggle] < runs[1][0]  # from t = 0
    assert runs[1][0] < at[linear] < runs[2][0]  # from t = 0.01
    # At t = 0.02 the shaker's motion ends before its mesh is removed.
    assert runs[2][0] < at["unfix move_shaker"] < at["unfix walls"] < at["unfix wall_shaker"]
    assert at["unfix wall_shaker"] < runs[3][0]
    assert runs[3][0] < at["unfix move_floor"] < runs[4][0]  # stops at 0.03


def test_liggghts_moves_the_walls_as_their_poses_say(tmp_path):
    """``dump mesh/stl`` every millisecond against ``Wall.vertices_at``: translation and rotation
    (each stopping, the rotation reversing on the way) to the dump's precision, the wiggle within
    ``A omega dt`` (LIGGGHTS sums velocity x step), across the run splits at 0.01, 0.013, 0.025
    and 0.03 s."""
    walls = [
        _plate(
            "floor",
            WallMotion("translation", velocity=(0, 0, 0.1), start_time=0.01, stop_time=0.03),
        ),
        _plate(
            "shaker",
            WallMotion("oscillation", amplitude=(0.002, 0.001, 0), period=0.0133, start_time=0.005),
            z=0.05,
        ),
        _plate(
            "spinner",
            WallMotion(
                "rotation",
                axis=(0, 0, 1),
                origin=(0.001, 0, 0),
                omega=30.0,
                stop_time=0.025,
                reverse_times=(0.013,),
            ),
            z=0.02,
        ),
    ]
    scene = _moving_scene(
        walls=walls, frame_dt=0.001, domain_lo=(-0.04, -0.04, -0.01), domain_hi=(0.04, 0.04, 0.07)
    )
    for wall in walls:
        write_ascii_stl(wall, tmp_path / f"{wall.name}.stl")
    script = render_input(scene, seed=1).splitlines()
    script.insert(script.index("dump_modify dmp sort id"), "dump dstl all mesh/stl 50 mesh_*.stl")
    (tmp_path / "in.liggghts").write_text("\n".join(script) + "\n")
    subprocess.run(
        [find_liggghts(), "-in", "in.liggghts"], cwd=tmp_path, check=True, capture_output=True
    )
    wiggle = 0.002 * 2 * math.pi / 0.0133 * scene.dem_dt
    dumps = sorted(tmp_path.glob("mesh_*.stl"))
    assert len(dumps) == 41
    for path in dumps:
        t = int(path.stem.split("_")[1]) * scene.dem_dt
        lines = path.read_text().splitlines()
        got = np.array([line.split()[1:4] for line in lines if "vertex" in line], float)
        for k, wall in enumerate(walls):  # the dump holds the meshes in order, 2 triangles each
            want = wall.vertices_at(t)[wall.faces].reshape(-1, 3)
            tol = 2e-6 + (wiggle if wall.name == "shaker" else 0.0)
            np.testing.assert_allclose(got[6 * k : 6 * k + 6], want, atol=tol, err_msg=wall.name)


def test_wall_set_velocities_follow_translation_and_oscillation():
    scene = _moving_scene()
    walls = WallSet(scene)
    points = torch.tensor([[0.0, 0.0, 0.0005], [0.0, 0.0, 0.0505]], dtype=torch.float64)
    for t in (0.005, 0.015, 0.035):
        found = walls.contacts(points + torch.tensor(scene.walls[0].motion.pose(t)[1]), 0.001, t)
        by_wall = {int(i >= 2): v for i, v in zip(found.tri_idx, found.velocity, strict=True)}
        np.testing.assert_allclose(by_wall[0], scene.walls[0].motion.linear_velocity(t))
        if t < 0.02:  # the shaker is there
            shaker = scene.walls[1].motion
            np.testing.assert_allclose(by_wall[1], shaker.linear_velocity(t))
            assert np.linalg.norm(by_wall[1]) > 0


def test_swept_bounds_cover_every_pose():
    scene = _moving_scene()
    for wall in scene.walls:
        lo, hi = wall.swept_bounds(scene.duration)
        for t in np.linspace(0, scene.duration, 41):
            if wall.present(t):
                v = wall.vertices_at(t)
                assert (v >= lo - 1e-15).all() and (v <= hi + 1e-15).all()


# --- Scene.kind, size distributions, regions and the dict round trip --------------------------


def test_kind_defaults_from_the_name_and_is_validated():
    assert make_hopper().kind == "hopper" and make_drum().kind == "drum"
    spec = ParticleSpec(1, 0.001, (0, 0, 0), (1, 1, 1))
    assert Scene("imported", [], spec).kind == "other"
    assert Scene("drum", [], spec).kind == "drum"
    with pytest.raises(InputError, match="kind must be one of"):
        Scene("x", [], spec, kind="silo")


def test_size_distribution_and_cylinder_region():
    p = ParticleSpec.cylinder_region(
        100, 0.002, (0.01, -0.02), 0.03, (0.05, 0.09), radii=(0.001, 0.002), radius_weights=(3, 1)
    )
    assert p.fill_shape == "cylinder" and p.cylinder == pytest.approx(
        (0.01, -0.02, 0.03, 0.05, 0.09)
    )
    assert p.size_distribution == ((0.001, 0.002), (0.75, 0.25))
    assert p.fill_volume == pytest.approx(math.pi * 0.03**2 * 0.04)
    assert p.mean_volume == pytest.approx(4 / 3 * math.pi * (0.75e-9 + 0.25 * 8e-9))
    with pytest.raises(InputError, match="largest of radii"):
        ParticleSpec(1, 0.001, (0, 0, 0), (1, 1, 1), radii=(0.001, 0.002))
    with pytest.raises(InputError, match="radius_weights"):
        ParticleSpec(1, 0.002, (0, 0, 0), (1, 1, 1), radii=(0.001, 0.002), radius_weights=(1,))
    with pytest.raises(InputError, match="square x-y"):
        ParticleSpec(1, 0.001, (0, 0, 0), (1, 2, 1), fill_shape="cylinder")


def test_polydisperse_cylinder_renders_templates_and_a_numberbased_distribution():
    scene = make_hopper()
    scene.particles = ParticleSpec.cylinder_region(
        500, 0.0015, (0.0, 0.0), 0.01, (0.06, 0.09), radii=(0.001, 0.0015), radius_weights=(1, 3)
    )
    script = render_input(scene, seed=3)
    assert "radius constant 0.001\n" in script and "radius constant 0.0015\n" in script
    assert "fix pdd all particledistribution/discrete/numberbased" in script
    assert " 2 pts 0.25 pts_2 0.75\n" in script
    assert "region fill cylinder z 0.0 0.0 0.01 0.06 0.09 units box" in script
    seeds = [int(line.split()[4]) for line in script.splitlines() if "particletemplate" in line]
    assert len(set(seeds)) == 2


#: SHA-256 of render_input(make_hopper(), 3) and render_input(make_drum(), 3) before the mesh
#: scenes came: the shipped scenes' LIGGGHTS input must not change by a byte.
RENDER_SHA256 = {
    "hopper": "02ed1c950b8fb9ef1aa3dad767d4e35488bfe9dae11f75b7e20c33281772b936",
    "drum": "bd31e77780f8e20aafc581f08a35033169b95104bd4d7cb3e6f8633779dcea01",
}


@pytest.mark.parametrize("build", [make_hopper, make_drum])
def test_existing_scenes_render_byte_identically(build):
    script = render_input(build(), seed=3)
    assert hashlib.sha256(script.encode()).hexdigest() == RENDER_SHA256[build().name]


def test_scene_dict_round_trip_keeps_the_new_fields(tmp_path):
    scene = _moving_scene(kind="other")
    scene.particles = ParticleSpec.cylinder_region(
        10, 0.002, (0.0, 0.0), 0.01, (0.01, 0.03), radii=(0.001, 0.002), radius_weights=(1, 2)
    )
    again = Scene.from_dict(scene.to_dict())
    assert again.to_dict() == scene.to_dict()
    assert again.walls[0].motion == scene.walls[0].motion
    assert again.particles == scene.particles and again.kind == "other"
    # ...and through an HDF5 trajectory file.
    pos = np.zeros((1, 2, 3), np.float32)
    traj = Trajectory(pos, pos, [0.001, 0.002], [1, 2], [0.0], scene=scene)
    write_trajectory(traj, tmp_path / "t.h5")
    assert read_trajectory(tmp_path / "t.h5").scene.to_dict() == scene.to_dict()


def test_old_scene_dicts_without_the_new_fields_still_load():
    data = make_drum().to_dict()
    del data["kind"]
    for key in ("radii", "radius_weights", "fill_shape"):
        del data["particles"][key]
    for key in ("velocity", "amplitude", "period", "stop_time"):
        del data["walls"][0]["motion"][key]
    scene = Scene.from_dict(data)
    assert scene.kind == "drum" and scene.particles.radii is None
    assert scene.to_dict() == make_drum().to_dict()
    # The shipped sample files were written before these fields existed.
    for kind in ("hopper", "drum"):
        assert read_trajectory(SAMPLES / kind / "traj_0000.h5").scene.kind == kind


# --- STL files, units, the example meshes ---------------------------------------------------


def _tetra(path, scale: float, ascii: bool = False):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * scale
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    if ascii:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        path.write_text(mesh.export(file_type="stl_ascii"))
    else:
        examples.write_binary_stl(path, vertices, faces)
    return path


def test_stl_units_scale_the_coordinates(tmp_path):
    mm = load_stl(_tetra(tmp_path / "a.stl", 40.0), "mm")[0]
    m = load_stl(_tetra(tmp_path / "b.stl", 40.0), "m")[0]
    cm = load_stl(_tetra(tmp_path / "c.stl", 40.0, ascii=True), "cm")[0]
    np.testing.assert_allclose(mm * 1000, m, rtol=1e-12)
    np.testing.assert_allclose(cm * 100, m, rtol=1e-12)
    assert np.ptp(mm, axis=0).max() == pytest.approx(0.04)
    with pytest.raises(InputError, match="units"):
        load_stl(tmp_path / "a.stl", "inch")
    with pytest.raises(FileNotFoundError, match="looked in"):
        load_stl("no_such_file.stl")


def test_mesh_scene_walls_follow_units_scale_and_offset(tmp_path):
    path = _tetra(tmp_path / "box.stl", 100.0)  # 0.1 m edges in mm
    scene = make_mesh_scene(
        walls={"tet": {"file": str(path), "units": "mm", "scale": 2.0, "offset": [0.01, 0, 0]}},
        insertion={"shape": "box", "lo": [0.025, 0.025, 0.025], "hi": [0.035, 0.035, 0.035]},
        num_particles=5,
        particle_radius=0.001,
        scale=0.5,
    )
    v = scene.wall("tet").vertices
    np.testing.assert_allclose(v.min(0), [0.005, 0, 0], atol=1e-15)
    np.testing.assert_allclose(v.max(0), [0.105, 0.1, 0.1], atol=1e-15)
    np.testing.assert_allclose(scene.particles.fill_lo, [0.0125] * 3)
    assert scene.kind == "other" and scene.outflow_z is None
    spin = {"kind": "rotation", "axis": [0, 0, 1], "omega": 2.0, "reverse_times": [0.5, 0.9]}
    rocked = make_mesh_scene(
        walls={"tet": {"file": str(path), "units": "mm", "motion": spin}},
        insertion={"shape": "box", "lo": [0.015, 0.015, 0.015], "hi": [0.025, 0.025, 0.025]},
        num_particles=5,
        particle_radius=0.001,
    )
    assert rocked.wall("tet").motion.reverse_times == (0.5, 0.9)


def test_example_meshes_reproduce_the_shipped_files_byte_identically(tmp_path):
    paths = examples.main(["--out", str(tmp_path)])
    assert sorted(p.name for p in paths) == sorted(p.name for p in MESH_DIR.glob("*.stl"))
    for path in paths:
        assert path.read_bytes() == (MESH_DIR / path.name).read_bytes(), path.name
        assert path.stat().st_size < 200_000


def test_example_meshes_are_well_formed():
    meshes = {name: load_stl(f"{name}.stl") for name in examples.example_meshes()}
    for name, (v, f) in meshes.items():
        check_wall_for_liggghts(Wall(name, v, f))
    # The lids close the outlets exactly: their rims are the outlets' rims.
    lids = {"cone_hopper": "cone_lid", "pyramid_hopper": "pyramid_lid", "silo": "silo_lid"}
    for body, lid in lids.items():
        rim = {
            tuple(p)
            for p in meshes[lid][0]
            if np.hypot(*(p[:2] - meshes[lid][0].mean(0)[:2])) > 1e-3
        }
        # Every lid vertex but its centre lies on the outlet's rim.
        assert len(rim) == len(meshes[lid][0]) - 1 and rim <= {tuple(p) for p in meshes[body][0]}
        assert (
            is_closed_surface(
                np.concatenate([meshes[body][0][meshes[body][1]], meshes[lid][0][meshes[lid][1]]])
            )
            is False
        )
    drum = np.concatenate([v[f] for v, f in (meshes["drum_shell"], meshes["drum_lifters"])])
    assert is_closed_surface(drum)
    shell = trimesh.Trimesh(*meshes["drum_shell"])
    assert shell.is_watertight and shell.volume > 0  # normals point outwards
    bars = trimesh.Trimesh(*meshes["drum_lifters"])
    assert bars.is_watertight and bars.volume == pytest.approx(4 * 0.006 * 0.004 * 0.03, rel=1e-6)


def test_inside_tests_agree_with_trimesh():
    v, f = load_stl("drum_shell.stl")
    lv, lf = load_stl("drum_lifters.stl")
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.05, 0.05, size=(400, 3))
    points[:, 1] *= 0.4
    tris = np.concatenate([v[f], lv[lf]])
    want = trimesh.Trimesh(v, f).contains(points) & ~trimesh.Trimesh(lv, lf).contains(points)
    np.testing.assert_array_equal(inside_closed_surface(points, tris), want)
    hull = inside_convex_hull(points, v)
    np.testing.assert_array_equal(hull, trimesh.Trimesh(v, f).contains(points))


def test_inside_convex_hull_with_a_tolerance_per_point_and_a_hull_built_once():
    """The unit cube: a point 0.1 m from its nearest face is inside by a tolerance below 0.1 m
    and not above; one tolerance per point gives each point's own answer, the same from the
    vertices or from a hull built once."""
    cube = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    points = np.array([[0.1, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.95], [1.2, 0.5, 0.5]])
    tol = np.array([0.09, 0.45, 0.06, -0.25])
    want = np.array([True, True, False, True])
    np.testing.assert_array_equal(inside_convex_hull(points, cube, tol=tol), want)
    np.testing.assert_array_equal(inside_convex_hull(points, ConvexHull(cube), tol=tol), want)
    np.testing.assert_array_equal(inside_convex_hull(points, cube, tol=0.11), [0, 1, 0, 0])


# --- the example scenes and their insertion regions -------------------------------------------


@pytest.mark.parametrize("config", [*CONFIGS, "mesh"])  # mesh: the users' template
def test_example_scenes_build_and_their_regions_pass(config):
    scene = _build(config)
    assert scene.name == config and scene.kind == ("drum" if "drum" in config else "hopper")
    check_insertion_region(scene)
    for wall in scene.walls:
        check_wall_for_liggghts(wall)
    centre = (np.asarray(scene.particles.fill_lo) + scene.particles.fill_hi) / 2
    assert inside_walls(centre[None], scene)[0]


def test_generate_ranges_sample_the_flat_keys():
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("generate", overrides=["scene=mesh_lifter_drum", "n=3"])
    for entry in plan_trajectories(cfg):
        params = entry["params"]
        assert 1.0 <= params["omega"] <= 4.0 and 0.3 <= params["friction"] <= 0.7
        scene = instantiate(params, _convert_="all")
        assert {w.motion.omega for w in scene.walls} == {params["omega"]}
        assert scene.materials.friction == params["friction"]


def _cylinder(radius: float, z: list[float], centre=(0.0, 0.0)) -> dict:
    return {"shape": "cylinder", "centre": list(centre), "radius": radius, "z": z}


@pytest.mark.parametrize(
    ("insertion", "message"),
    [
        # Above the silo's open top.
        (_cylinder(0.02, [0.09, 0.12]), r"insertion cylinder .* lies outside the bounding box"),
        # Wider than the silo: through its wall.
        (
            _cylinder(0.034, [0.04, 0.08]),
            "crosses or comes within one particle radius .* wall silo",
        ),
        ({"shape": "box", "lo": [0.02, -0.01, 0.04], "hi": [0.034, 0.01, 0.08]}, "wall silo"),
        # Through the lid into the outlet, down to the outflow plane.
        (_cylinder(0.004, [-0.04, 0.05], (0.015, 0.0)), "below the outflow plane"),
        (_cylinder(0.004, [0.001, 0.05], (0.015, 0.0)), "wall lid"),
    ],
)
def test_regions_crossing_or_outside_the_walls_are_refused(insertion, message):
    with pytest.raises(InputError, match=message) as err:
        _build("mesh_silo", insertion=insertion)
    assert "move or shrink `insertion`" in str(err.value)  # the fix


def test_region_outside_a_closed_drum_is_refused():
    # Inside the drum's bounding box but beyond its shell (a corner of the box).
    corner = {"shape": "box", "lo": [0.036, -0.01, 0.036], "hi": [0.042, 0.01, 0.042]}
    with pytest.raises(InputError, match="lies outside the closed surface"):
        _build("mesh_lifter_drum", insertion=corner)


def test_wall_inside_the_region_is_refused():
    scene = _build("mesh_silo")
    vertices, faces = load_stl("silo_lid.stl")  # a small disc, moved into the region
    scene.walls.append(Wall("baffle", vertices * 0.2 + [0.0, 0.0, 0.07], faces))
    with pytest.raises(InputError, match=r"wall baffle has \d+ vertices inside the insertion"):
        check_insertion_region(scene)


# --- tiny real LIGGGHTS runs ------------------------------------------------------------------


def _tiny(config: str, *overrides: str, **changes):
    scene = _build(config, *overrides, **changes)
    traj, run = simulate(scene, seed=7, progress=False)
    return scene, traj, run


def _outside_hull_above(traj, scene, z0: float) -> int:
    """Particles whose centre is above ``z0`` but outside the walls' convex hull in any frame."""
    triangles, _ = walls_at(scene, 0.0)
    pos = traj.positions.reshape(-1, 3).astype(np.float64)
    keep = np.isfinite(pos).all(1) & (pos[:, 2] > z0)
    return int((~inside_convex_hull(pos[keep], triangles.reshape(-1, 3), tol=-1e-9)).sum())


@pytest.mark.slow
def test_tiny_cone_hopper_run_keeps_particles_inside_and_drains():
    scene, traj, run = _tiny(
        "mesh_cone",
        "scene.build.num_particles=300",
        "scene.build.settle_time=0.2",
        "scene.build.duration=0.1",
        "scene.build.frame_dt=0.01",
        "scene.build.walls.lid.removal_time=0.02",
    )
    assert run.inserted == 300 and traj.num_frames == 11
    assert _outside_hull_above(traj, scene, 0.0) == 0
    count = traj.present.sum(1)
    assert count[0] == 300 and np.all(np.diff(count) <= 0)
    below = traj.positions[:3, :, 2]  # frames up to t = 0.02: the lid is still there
    assert np.nanmin(below) > 0.0


@pytest.mark.slow
def test_tiny_silo_run_with_two_radii_keeps_particles_inside():
    scene, traj, run = _tiny(
        "mesh_silo",
        "scene.build.num_particles=300",
        "scene.build.settle_time=0.2",
        "scene.build.duration=0.1",
        "scene.build.frame_dt=0.01",
        "scene.build.walls.lid.removal_time=0.02",
        particle_radius=None,
        particle_radii=[0.0012, 0.0016],
    )
    assert run.inserted == 300
    assert _outside_hull_above(traj, scene, 0.0) == 0
    count = traj.present.sum(1)
    assert count[0] == 300 and np.all(np.diff(count) <= 0)
    # Per-particle radii: both sizes, about half each.
    values, counts = np.unique(traj.radii, return_counts=True)
    np.testing.assert_allclose(values, [0.0012, 0.0016], rtol=1e-6)
    assert counts.min() > 100


@pytest.mark.slow
def test_tiny_lifter_drum_run_conserves_particles_inside_the_shell():
    scene, traj, run = _tiny(
        "mesh_lifter_drum",
        "scene.build.num_particles=300",
        "scene.build.settle_time=0.2",
        "scene.build.duration=0.1",
        "scene.build.frame_dt=0.01",
        "scene.build.omega=4.0",
    )
    assert run.inserted == 300
    assert traj.present.all()  # closed: mass conserved
    for frame, t in enumerate(traj.times):
        triangles, _ = walls_at(scene, float(t))
        inside = inside_closed_surface(traj.positions[frame].astype(np.float64), triangles)
        assert inside.all(), f"{(~inside).sum()} particles outside the drum at t = {t}"


@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS)
def test_full_size_example_scene_passes_the_physics_sanity_checks(config):
    """One full-size LIGGGHTS run per example scene at its defaults (1-2 s recorded, 1,800-2,000
    particles): no particle ever crosses a wall or starts outside them (the evaluation's leak
    metric on the ground truth), particles are conserved in the closed drum and only leave
    through the outflow of the hoppers, which do discharge."""
    from granular_pyg.metrics import leaked_particles

    scene = _build(config)
    traj, run = simulate(scene, seed=11, progress=False)
    assert run.inserted == scene.particles.count
    assert leaked_particles(traj.positions, scene, traj.times) == 0
    count = traj.present.sum(1)
    if scene.outflow_z is None:
        assert (count == scene.particles.count).all()
    else:
        assert count[0] == scene.particles.count and np.all(np.diff(count) <= 0)
        assert count[-1] < count[0]  # it discharges
        gone = ~traj.present[-1]
        last_seen = np.array(
            [traj.positions[:, i, 2][traj.present[:, i]][-1] for i in np.flatnonzero(gone)]
        )
        assert (last_seen < scene.outflow_z + 0.05).all()  # they left through the bottom


def test_pyramid_hopper_walls_converge_both_ways_onto_its_square_outlet():
    meshes = examples.pyramid_hopper()
    vertices, faces = meshes["pyramid_hopper"]
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    inclined = np.abs(normal[:, 2]) > 1e-9
    # Wall angles to the horizontal: 57.0 (-x), 65.8 (+x), 61.2 deg (+-y), from the sizes.
    angles = np.round(np.degrees(np.arccos(-normal[inclined, 2])), 1)
    np.testing.assert_allclose(np.unique(angles), [57.0, 61.2, 65.8], atol=0.05)
    # Inclined walls face all four horizontal directions: the outlet converges both ways.
    facing = np.unique(np.sign(np.round(normal[inclined, :2], 6)), axis=0)
    assert {tuple(f) for f in facing} == {(-1, 0), (1, 0), (0, -1), (0, 1)}
    # Normals point out of the particle space (away from the vertical through the outlet).
    centre = tri.mean(1)
    assert np.all(((centre[:, :2] - [0.004, 0.0]) * normal[:, :2]).sum(1) > 0)
    lid_v, _ = meshes["pyramid_lid"]
    np.testing.assert_allclose(np.ptp(lid_v[:, :2], axis=0), [0.02, 0.02], atol=1e-12)
