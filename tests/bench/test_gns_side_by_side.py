"""The gns side-by-side's converter: gns's files, walls as kinematic particles on the meshes,
and gns's normalisation statistics (no gns checkout needed)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from granular_pyg.geometry import closest_point_on_triangles
from granular_pyg.io import read_trajectory
from granular_pyg.samples import sample_files
from tools.gns_side_by_side import (
    GNS_GRAIN_TYPE,
    GNS_KINEMATIC_TYPE,
    convert,
    sample_triangles,
)

SPLITS = ("train", "valid", "test")
METADATA_KEYS = {
    "bounds",
    "sequence_length",
    "default_connectivity_radius",
    "dim",
    "dt",
    "vel_mean",
    "vel_std",
    "acc_mean",
    "acc_std",
}


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    out = tmp_path_factory.mktemp("gns_side_by_side")
    conversion = convert(out)
    metadata = json.loads((out / "data" / "metadata.json").read_text())
    data = {}
    for split in SPLITS:
        with np.load(out / "data" / f"{split}.npz", allow_pickle=True) as npz:
            data[split] = {key: tuple(npz[key]) for key in npz.files}
    return conversion, metadata, data


def _distance_to_mesh(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``[P]`` distance (m) of each point to the nearest of ``triangles [F, 3, 3]``."""
    p = torch.from_numpy(points.astype(np.float64))
    tri = torch.from_numpy(triangles.astype(np.float64))
    pairs_p = p[:, None].expand(-1, len(tri), -1).reshape(-1, 3)
    pairs_t = tri[None].expand(len(p), -1, -1, -1).reshape(-1, 3, 3)
    _, sq = closest_point_on_triangles(pairs_p, pairs_t)
    return sq.view(len(p), len(tri)).min(dim=1).values.sqrt().numpy()


def test_files_have_gns_keys_shapes_and_no_nan(converted):
    conversion, metadata, data = converted
    assert set(metadata) == METADATA_KEYS
    assert metadata["dim"] == 3
    assert metadata["default_connectivity_radius"] == pytest.approx(0.0075)
    assert np.asarray(metadata["bounds"]).shape == (3, 2)
    assert all(len(metadata[k]) == 3 for k in ("vel_mean", "vel_std", "acc_mean", "acc_std"))
    frames = metadata["sequence_length"]
    assert frames == conversion.frames >= 7
    for split in SPLITS:
        files = sample_files("hopper", split)
        assert sorted(data[split]) == [f"simulation_{i}" for i in range(len(files))]
        for i, path in enumerate(files):
            positions, types = data[split][f"simulation_{i}"]
            grains = conversion.particles[path.name]
            walls = conversion.wall_particles[path.name]
            assert positions.dtype == np.float32
            assert positions.shape == (frames, grains + walls, 3)
            assert types.shape == (grains + walls,)
            assert np.issubdtype(types.dtype, np.integer)
            assert (types[:grains] == GNS_GRAIN_TYPE).all()
            assert (types[grains:] == GNS_KINEMATIC_TYPE).all()
            assert walls > 0
            assert np.isfinite(positions).all()
            # The grains are the trajectory's own positions over the kept frames.
            start = conversion.first_frames[path.name]
            original = read_trajectory(path).positions[start : start + frames]
            np.testing.assert_array_equal(positions[:, :grains], original)


def test_kinematic_particles_lie_on_the_present_walls(converted):
    conversion, _, data = converted
    path = sample_files("hopper", "train")[0]
    traj = read_trajectory(path)
    start = conversion.first_frames[path.name]
    positions, types = data["train"]["simulation_0"]
    kinematic = positions[:, types == GNS_KINEMATIC_TYPE]
    for frame in (0, len(positions) - 1):
        t = float(traj.times[start + frame])
        walls = [w for w in traj.scene.walls if w.present(t)]
        assert len(walls) < len(traj.scene.walls)  # the lid is gone
        triangles = np.concatenate([w.vertices_at(t)[w.faces] for w in walls])
        assert _distance_to_mesh(kinematic[frame], triangles).max() < 1e-6
    # Static walls: the kinematic particles do not move.
    np.testing.assert_array_equal(kinematic[0], kinematic[-1])


def test_statistics_match_brute_force(converted):
    conversion, metadata, _ = converted
    vel, acc = [], []
    for path in sample_files("hopper", "train"):
        start = conversion.first_frames[path.name]
        x = read_trajectory(path).positions[start : start + conversion.frames].astype(np.float64)
        for particle in range(x.shape[1]):
            for frame in range(1, x.shape[0]):
                vel.append(x[frame, particle] - x[frame - 1, particle])
                if frame >= 2:
                    acc.append(
                        x[frame, particle] - 2 * x[frame - 1, particle] + x[frame - 2, particle]
                    )
    vel, acc = np.array(vel), np.array(acc)
    for key, expected in (
        ("vel_mean", vel.mean(0)),
        ("vel_std", vel.std(0)),
        ("acc_mean", acc.mean(0)),
        ("acc_std", acc.std(0)),
    ):
        np.testing.assert_allclose(metadata[key], expected, rtol=1e-6, atol=1e-12, err_msg=key)


def test_triangle_sampling_is_a_poisson_disk_on_the_triangle():
    tri = np.array([[[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.03, 0.0]]])
    spacing = 0.003
    idx, bary = sample_triangles(tri, spacing)
    assert (idx == 0).all()
    assert np.allclose(bary.sum(1), 1.0) and (bary >= -1e-12).all()
    points = bary @ tri[0]
    gaps = np.linalg.norm(points[:, None] - points[None], axis=-1) + np.eye(len(points))
    assert gaps.min() >= spacing * (1 - 1e-6)
    # Every point of the triangle is within about one spacing of a sample.
    rng = np.random.default_rng(0)
    u = rng.random((500, 2))
    u = np.where(u.sum(1, keepdims=True) > 1, 1 - u, u)
    probes = u[:, :1] * tri[0, 1] + u[:, 1:] * tri[0, 2]
    nearest = np.linalg.norm(probes[:, None] - points[None], axis=-1).min(1)
    assert nearest.max() < 1.3 * spacing
