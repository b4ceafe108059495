"""Physics sanity of the bundled LIGGGHTS sample (real data, shipped as package data)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from granular_pyg.io import read_trajectory
from granular_pyg.metrics import centre_of_mass, discharged_fraction, dynamic_angle_of_repose
from granular_pyg.samples import SAMPLES_DIR, sample_files

HOPPERS = sample_files("hopper")
DRUMS = sample_files("drum")


def test_sample_size_and_shape():
    assert len(HOPPERS) >= 4 and len(DRUMS) >= 4
    total = sum(p.stat().st_size for p in SAMPLES_DIR.rglob("*.h5"))
    assert total <= 25e6, f"bundled sample is {total / 1e6:.1f} MB"
    for path in HOPPERS + DRUMS:
        traj = read_trajectory(path)
        assert traj.num_frames >= 200
        assert 800 <= traj.num_particles <= 2000
        assert traj.metadata["liggghts_version"].startswith("LIGGGHTS (Version")
    assert {p.name for p in sample_files("hopper", "test")} == {HOPPERS[-1].name}


def _hopper_clearance(traj) -> np.ndarray:
    """Signed distance (m, > 0 inside) of each particle centre above the outlet to the nearest
    hopper wall plane, NaN elsewhere. ``[T, N]``."""
    p = traj.scene.params
    alpha = math.radians(p["alpha_deg"])
    x, y, z = (traj.positions[..., k] for k in range(3))
    incline = z * math.cos(alpha) - (np.abs(x) - p["opening"] / 2) * math.sin(alpha)
    side = p["depth"] / 2 - np.abs(y)
    clearance = np.minimum(incline, side)
    return np.where(z >= 0, clearance, np.nan)


@pytest.mark.parametrize("path", HOPPERS, ids=lambda p: p.stem)
def test_hopper_particles_stay_inside_the_walls(path):
    traj = read_trajectory(path)
    radius = float(traj.radii.max())
    clearance = _hopper_clearance(traj)
    assert np.nanmin(clearance) > -radius
    # The lid holds everything up until t_open.
    closed = traj.times < traj.scene.wall("lid").removal_time
    assert (traj.positions[closed][..., 2] > -radius).all()


@pytest.mark.parametrize("path", HOPPERS, ids=lambda p: p.stem)
def test_hopper_discharges_after_the_lid_opens(path):
    traj = read_trajectory(path)
    below = discharged_fraction(traj.positions, outlet_z=0.0)
    t_open = traj.scene.wall("lid").removal_time
    assert (below[traj.times <= t_open] == 0).all()
    assert (np.diff(below) >= 0).all()  # mass below the opening grows monotonically
    assert below[-1] > 0.5


@pytest.mark.parametrize("path", DRUMS, ids=lambda p: p.stem)
def test_drum_particles_stay_inside_the_rotating_walls(path):
    traj = read_trajectory(path)
    wall = traj.scene.wall("drum")
    radius = float(traj.radii.max())
    for frame in range(0, traj.num_frames, 25):
        mesh = trimesh.Trimesh(traj.wall_vertices("drum", frame), wall.faces)
        inside = trimesh.proximity.signed_distance(mesh, traj.positions[frame])
        assert inside.min() > -radius, f"frame {frame}"


@pytest.mark.parametrize("path", DRUMS, ids=lambda p: p.stem)
def test_drum_bed_follows_the_rotation(path):
    traj = read_trajectory(path)
    omega = traj.scene.params["omega"]
    com = centre_of_mass(traj.positions)
    # Rotation about +y drags the bed towards -x (right-hand rule) and lifts it there.
    assert np.sign(com[-1, 0] - com[0, 0]) == -np.sign(omega)
    assert abs(com[-1, 0] - com[0, 0]) > 2 * float(traj.radii.max())
    angle = np.median([dynamic_angle_of_repose(traj.positions[f]) for f in range(100, 201, 10)])
    angle_at_rest = dynamic_angle_of_repose(traj.positions[0])
    print(f"{path.stem}: omega {omega:.2f} rad/s, dynamic angle of repose {angle:.1f} deg")
    assert angle_at_rest < 10.0  # a flat bed before the drum turns
    assert 20.0 < angle < 50.0
