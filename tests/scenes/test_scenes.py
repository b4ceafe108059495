"""Hopper and drum builders, and the Scene they return."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from granular_pyg.dem.liggghts import check_wall_for_liggghts
from granular_pyg.errors import InputError
from granular_pyg.geometry import closest_point_on_triangles, pose_about_axis
from granular_pyg.scenes import Scene, make_drum, make_hopper


def _distance_to_walls(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``[P]`` distance of each point to the nearest triangle (dense, float64)."""
    p = torch.from_numpy(points).repeat_interleave(len(triangles), 0)
    t = torch.from_numpy(triangles).repeat(len(points), 1, 1)
    _, sq = closest_point_on_triangles(p, t)
    return sq.reshape(len(points), len(triangles)).min(1).values.sqrt().numpy()


def _box_corners(lo, hi) -> np.ndarray:
    return np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )


@pytest.mark.parametrize("alpha", [50.0, 60.0, 80.0])
def test_hopper_walls_have_the_requested_angle_opening_and_lid(alpha):
    scene = make_hopper(alpha_deg=alpha, opening=0.018)
    hopper, lid = scene.wall("hopper"), scene.wall("lid")
    normals = np.cross(*(hopper.triangles[:, 1:] - hopper.triangles[:, :1]).transpose(1, 0, 2))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    tilt = np.degrees(np.arccos(np.abs(normals[:, 2])))
    # Every hopper triangle is vertical (90 deg, the y walls) or inclined at alpha.
    assert np.all(np.isclose(tilt, 90.0, atol=1e-6) | np.isclose(tilt, alpha, atol=1e-6))
    assert np.isclose(tilt, alpha, atol=1e-6).any()
    # The lid closes exactly the slot at z = 0 and is removed at t_open.
    assert np.allclose(lid.vertices[:, 2], 0.0)
    assert np.isclose(np.ptp(lid.vertices[:, 0]), 0.018)
    assert lid.removal_time == scene.params["t_open"] and hopper.removal_time is None
    assert lid.present(0.0) and not lid.present(scene.params["t_open"])
    assert scene.outflow_z == scene.domain_lo[2] < 0


@pytest.mark.parametrize("alpha", [50.0, 80.0])
def test_hopper_fill_region_lies_inside_the_walls(alpha):
    scene = make_hopper(alpha_deg=alpha)
    p = scene.particles
    corners = _box_corners(p.fill_lo, p.fill_hi)
    triangles = np.concatenate([w.triangles for w in scene.walls])
    assert (_distance_to_walls(corners, triangles) >= p.radius).all()
    # ...and inside the V: |x| below the wall's half-width at that height.
    half = scene.params["opening"] / 2 + corners[:, 2] / math.tan(math.radians(alpha))
    assert (np.abs(corners[:, 0]) < half).all()


def test_drum_is_a_closed_cylinder_about_y_with_the_fill_inside():
    scene = make_drum(drum_radius=0.05, length=0.03, sections=48)
    drum = scene.wall("drum")
    mesh = trimesh.Trimesh(drum.vertices, drum.faces)
    assert mesh.is_watertight
    assert np.isclose(np.ptp(drum.vertices[:, 1]), 0.03)
    radial = np.linalg.norm(drum.vertices[:, [0, 2]], axis=1)
    assert np.isclose(radial.max(), 0.05)
    corners = _box_corners(scene.particles.fill_lo, scene.particles.fill_hi)
    assert mesh.contains(corners).all()
    assert (_distance_to_walls(corners, drum.triangles) >= scene.particles.radius).all()
    assert scene.outflow_z is None


def test_drum_particle_count_follows_the_fill_fraction():
    small, large = make_drum(fill_fraction=0.2), make_drum(fill_fraction=0.4)
    assert large.particles.count == pytest.approx(2 * small.particles.count, rel=0.01)
    assert make_drum(num_particles=777).particles.count == 777


def test_drum_pose_is_the_right_handed_rotation_about_y():
    scene = make_drum(omega=2.0)
    wall = scene.wall("drum")
    rot, shift = wall.motion.pose(0.5)
    want_rot, want_shift = pose_about_axis((0, 1, 0), 1.0)
    np.testing.assert_allclose(rot, want_rot.numpy(), atol=1e-12)
    np.testing.assert_allclose(shift, want_shift.numpy(), atol=1e-12)
    # The bottom of the drum moves towards -x under positive omega about +y.
    bottom = np.array([[0.0, 0.0, -0.05]])
    assert (bottom @ rot.T + shift)[0, 0] < 0
    np.testing.assert_allclose(wall.vertices_at(0.0), wall.vertices)


@pytest.mark.parametrize("build", [make_hopper, make_drum])
def test_every_triangle_passes_the_liggghts_angle_check(build):
    for wall in build().walls:
        check_wall_for_liggghts(wall)


@pytest.mark.parametrize("build", [make_hopper, make_drum])
def test_scene_dict_round_trip(build):
    scene = build()
    again = Scene.from_dict(scene.to_dict())
    assert again.to_dict() == scene.to_dict()
    assert again.num_frames == scene.num_frames


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"alpha_deg": 95.0}, "alpha_deg"),
        ({"opening": 0.002}, "opening"),
        ({"t_open": 2.0}, "t_open"),
        ({"num_particles": 20000}, "fill region"),
    ],
)
def test_bad_hopper_parameters_are_named(kwargs, message):
    with pytest.raises(InputError, match=message):
        make_hopper(**kwargs)


def test_overfull_drum_is_rejected():
    with pytest.raises(InputError, match="fill_fraction"):
        make_drum(fill_fraction=0.7)


def test_frame_dt_must_be_a_multiple_of_the_dem_step():
    with pytest.raises(InputError, match="multiple of dem_dt"):
        make_hopper(frame_dt=0.00251)


def test_the_outlet_opens_when_the_lid_goes_and_never_in_a_closed_drum():
    assert make_hopper(t_open=0.125).opening_time == 0.125
    assert make_drum(drum_radius=0.05, length=0.03, sections=48).opening_time is None
