"""ParaView export: files read back with the right counts, poses and series."""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from granular_pyg.errors import InputError
from granular_pyg.io import export_paraview, read_trajectory, read_vtp, write_vtp
from granular_pyg.samples import sample_files


@pytest.mark.parametrize("fmt", ["binary", "ascii"])
def test_write_vtp_round_trips_points_data_and_triangles(tmp_path, fmt):
    pts = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    vel = np.arange(15, dtype=np.float64).reshape(5, 3)
    tris = np.array([[0, 1, 2], [2, 3, 4]])
    back = read_vtp(write_vtp(tmp_path / "a.vtp", pts, {"velocity": vel}, tris, fmt))
    np.testing.assert_array_equal(back["points"], pts)
    np.testing.assert_array_equal(back["velocity"], vel.astype(np.float32))
    assert back["connectivity"].tolist() == [0, 1, 2, 2, 3, 4]
    assert back["offsets"].tolist() == [3, 6]
    verts = read_vtp(write_vtp(tmp_path / "b.vtp", pts, fmt=fmt))
    assert verts["offsets"].tolist() == [1, 2, 3, 4, 5]


def test_write_vtp_rejects_nan_points_and_bad_triangles(tmp_path):
    with pytest.raises(InputError, match="NaN"):
        write_vtp(tmp_path / "a.vtp", np.full((2, 3), np.nan))
    with pytest.raises(InputError, match="indices"):
        write_vtp(tmp_path / "a.vtp", np.zeros((2, 3)), triangles=np.array([[0, 1, 2]]))
    assert not list(tmp_path.iterdir())  # nothing half-written


def _frames(path):
    return [
        (float(d.get("timestep")), int(d.get("part")), d.get("file"))
        for d in ET.parse(path).getroot().iter("DataSet")
    ]


def test_hopper_truth_and_prediction_side_by_side(tmp_path):
    truth = read_trajectory(sample_files("hopper", "test")[0])
    truth = dataclasses.replace(
        truth,
        positions=truth.positions[::20],
        velocities=truth.velocities[::20],
        times=truth.times[::20],
    )
    pred = dataclasses.replace(truth, positions=truth.positions.copy())
    pred.positions[-1, :7] = np.nan  # seven particles have left in the prediction
    pvd = export_paraview(tmp_path, {"truth": truth, "prediction": pred}, spacing=0.5)

    entries = _frames(pvd)
    assert len(entries) == 4 * truth.num_frames  # particles + walls of each, every frame
    last = truth.num_frames - 1
    name = f"particles_{last:06d}.vtp"
    t_last = read_vtp(tmp_path / "truth" / name)
    p_last = read_vtp(tmp_path / "prediction" / "shifted" / name)
    present = int(np.isfinite(truth.positions[-1]).all(1).sum())
    assert len(t_last["points"]) == present
    assert len(p_last["points"]) == int(np.isfinite(pred.positions[-1]).all(1).sum())
    assert set(t_last) >= {"velocity", "radius", "id", "speed"}
    # The prediction sits 0.5 m along x in all.pvd and unshifted in prediction.pvd.
    own = read_vtp(tmp_path / "prediction" / name)
    np.testing.assert_allclose(p_last["points"][:, 0] - own["points"][:, 0], 0.5, atol=1e-6)

    scene = truth.scene
    faces = {w.name: len(w.faces) for w in scene.walls}
    t_open = scene.params["t_open"]
    for f, t in enumerate(truth.times):
        walls = read_vtp(tmp_path / "truth" / f"walls_{f:06d}.vtp")
        lid = faces["lid"] if t < t_open else 0
        assert len(walls["offsets"]) == faces["hopper"] + lid


def test_drum_walls_are_written_at_their_pose(tmp_path):
    truth = read_trajectory(sample_files("drum", "test")[0])
    export_paraview(tmp_path, {"truth": truth}, every=50, progress=False)
    wall = truth.scene.walls[0]
    for f in range(0, truth.num_frames, 50):
        back = read_vtp(tmp_path / "truth" / f"walls_{f:06d}.vtp")
        want = wall.vertices_at(float(truth.times[f]))
        np.testing.assert_allclose(back["points"], want, atol=1e-6)
    assert len(_frames(tmp_path / "truth.pvd")) == 2 * len(range(0, truth.num_frames, 50))
