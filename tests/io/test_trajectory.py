"""The HDF5 trajectory format: exact round trips, atomic writes and clear errors."""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from granular_pyg.errors import InputError
from granular_pyg.io import Trajectory, read_trajectory, write_trajectory
from granular_pyg.io import trajectory as trajectory_module
from granular_pyg.scenes import ParticleSpec, Scene, Wall, WallMotion

_ARRAYS = ("positions", "velocities", "radii", "ids", "times")


def _scene() -> Scene:
    box = Wall(
        name="drum",
        vertices=np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], float) / 3,
        faces=np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]),
        motion=WallMotion(
            kind="rotation", axis=(0.0, 1.0, 0.0), origin=(0.01, 0.0, 0.02), omega=1.7
        ),
    )
    lid = Wall(
        name="lid",
        vertices=np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.0, 0.05, 0.0]]),
        faces=np.array([[0, 1, 2]]),
        removal_time=0.0125,
    )
    return Scene(
        name="test",
        walls=[box, lid],
        particles=ParticleSpec(
            count=7, radius=1.5e-3, fill_lo=(-0.01, -0.01, 0.0), fill_hi=(0.01, 0.01, 0.05)
        ),
        domain_lo=(-0.1, -0.1, -0.05),
        domain_hi=(0.1, 0.1, 0.2),
        outflow_z=-0.05,
        frame_dt=2.5e-3,
        params={"alpha": 30.0, "opening": 0.01},
    )


def _trajectory(num_frames: int = 6, num_particles: int = 7, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(num_frames, num_particles, 3)).astype(np.float32)
    velocities = rng.normal(size=(num_frames, num_particles, 3)).astype(np.float32)
    leave = rng.integers(1, num_frames + 1, size=num_particles)  # frame each particle leaves
    gone = np.arange(num_frames)[:, None] >= leave[None, :]
    positions[gone] = np.nan
    velocities[gone] = np.nan
    return Trajectory(
        positions=positions,
        velocities=velocities,
        radii=rng.uniform(1e-3, 2e-3, num_particles).astype(np.float32),
        ids=np.sort(rng.choice(10 * num_particles + 10, num_particles, replace=False)) + 1,
        times=np.arange(num_frames) * 2.5e-3 + 0.1 / 3,
        scene=_scene(),
        metadata={"seed": 3, "liggghts_version": "3.8.0", "params": {"omega": [1.7, None]}},
    )


def _assert_same_arrays(a: Trajectory, b: Trajectory) -> None:
    for name in _ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=name in ("positions", "velocities")), name


def test_round_trip_is_exact(tmp_path):
    traj = _trajectory()
    write_trajectory(traj, tmp_path / "t.h5")
    back = read_trajectory(tmp_path / "t.h5")
    _assert_same_arrays(traj, back)


def test_round_trip_keeps_nan_in_the_same_places(tmp_path):
    traj = _trajectory()
    write_trajectory(traj, tmp_path / "t.h5")
    assert np.array_equal(read_trajectory(tmp_path / "t.h5").present, traj.present)


def test_round_trip_keeps_the_scene_dict(tmp_path):
    traj = _trajectory()
    write_trajectory(traj, tmp_path / "t.h5")
    assert read_trajectory(tmp_path / "t.h5").scene.to_dict() == traj.scene.to_dict()


def test_round_trip_keeps_the_metadata(tmp_path):
    traj = _trajectory()
    write_trajectory(traj, tmp_path / "t.h5")
    assert read_trajectory(tmp_path / "t.h5").metadata == traj.metadata


def test_round_trip_without_a_scene_gives_none(tmp_path):
    traj = _trajectory()
    traj.scene = None
    write_trajectory(traj, tmp_path / "t.h5")
    assert read_trajectory(tmp_path / "t.h5").scene is None


def test_wall_vertices_follow_the_rotation(tmp_path):
    traj = _trajectory()
    write_trajectory(traj, tmp_path / "t.h5")
    back = read_trajectory(tmp_path / "t.h5")
    expected = traj.scene.wall("drum").vertices_at(float(traj.times[3]))
    assert np.array_equal(back.wall_vertices("drum", 3), expected)


def test_file_layout_is_the_documented_one(tmp_path):
    write_trajectory(_trajectory(num_frames=40), tmp_path / "t.h5")
    with h5py.File(tmp_path / "t.h5", "r") as h5:
        layout = (
            h5.attrs["format"],
            int(h5.attrs["format_version"]),
            h5["positions"].chunks,
            h5["positions"].compression,
            h5["positions"].shuffle,
            h5["scene/walls/drum/faces"].dtype,
            h5["scene/walls/lid/vertices"].dtype,
        )
    assert layout == (
        "granular_pyg.trajectory",
        1,
        (16, 7, 3),  # chunks of 16 frames
        "gzip",
        True,
        np.dtype(np.int64),
        np.dtype(np.float64),
    )


@settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    num_frames=st.integers(1, 5),
    num_particles=st.integers(0, 6),
    seed=st.integers(0, 2**16),
    with_scene=st.booleans(),
)
def test_round_trip_is_exact_for_random_shapes(
    tmp_path, num_frames, num_particles, seed, with_scene
):
    traj = _trajectory(num_frames, num_particles, seed)
    if not with_scene:
        traj.scene = None
    write_trajectory(traj, tmp_path / "t.h5")
    back = read_trajectory(tmp_path / "t.h5")
    _assert_same_arrays(traj, back)


def test_truncated_file_raises_naming_the_path(tmp_path):
    path = tmp_path / "cut.h5"
    write_trajectory(_trajectory(50, 200), path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.h5.*(corrupt|truncated)"):
        read_trajectory(path)


def test_garbage_file_raises_input_error(tmp_path):
    path = tmp_path / "garbage.h5"
    path.write_bytes(b"this is not an HDF5 file\n" * 10)
    with pytest.raises(InputError, match=r"garbage\.h5"):
        read_trajectory(path)


def test_missing_file_raises_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothere\.h5"):
        read_trajectory(tmp_path / "nothere.h5")


def test_wrong_format_attribute_raises(tmp_path):
    path = tmp_path / "other.h5"
    write_trajectory(_trajectory(), path)
    with h5py.File(path, "a") as h5:
        h5.attrs["format"] = "someone.else"
    with pytest.raises(InputError, match=r"other\.h5.*someone\.else"):
        read_trajectory(path)


def test_missing_dataset_is_named(tmp_path):
    path = tmp_path / "t.h5"
    write_trajectory(_trajectory(), path)
    with h5py.File(path, "a") as h5:
        del h5["velocities"]
    with pytest.raises(InputError, match=r"t\.h5.*'/velocities' is missing"):
        read_trajectory(path)


def test_missing_wall_dataset_is_named(tmp_path):
    path = tmp_path / "t.h5"
    write_trajectory(_trajectory(), path)
    with h5py.File(path, "a") as h5:
        del h5["scene/walls/lid/faces"]
    with pytest.raises(InputError, match=r"scene/walls/lid/faces"):
        read_trajectory(path)


def test_inconsistent_shapes_in_the_file_raise(tmp_path):
    path = tmp_path / "t.h5"
    write_trajectory(_trajectory(), path)
    with h5py.File(path, "a") as h5:
        del h5["radii"]
        h5["radii"] = np.ones(3, np.float32)
    with pytest.raises(InputError, match=r"t\.h5: radii"):
        read_trajectory(path)


def test_interrupted_write_keeps_the_old_file_and_leaves_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "t.h5"
    old = _trajectory(seed=1)
    write_trajectory(old, path)
    before = path.read_bytes()

    def fail(*args, **kwargs):
        raise RuntimeError("killed mid-write")

    monkeypatch.setattr(trajectory_module, "_write_scene", fail)
    with pytest.raises(RuntimeError, match="killed"):
        write_trajectory(_trajectory(seed=2), path)
    assert (path.read_bytes(), sorted(p.name for p in tmp_path.iterdir())) == (before, ["t.h5"])


def test_interrupted_first_write_leaves_nothing(tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise RuntimeError("killed mid-write")

    monkeypatch.setattr(trajectory_module, "_write_scene", fail)
    with pytest.raises(RuntimeError, match="killed"):
        write_trajectory(_trajectory(), tmp_path / "t.h5")
    assert list(tmp_path.iterdir()) == []


def test_metadata_that_is_not_json_raises(tmp_path):
    traj = _trajectory()
    traj.metadata = {"seed": object()}
    with pytest.raises(InputError, match="metadata"):
        write_trajectory(traj, tmp_path / "t.h5")


def test_inputs_are_cast_to_the_documented_dtypes():
    traj = _trajectory()
    cast = Trajectory(
        positions=traj.positions.astype(np.float64),
        velocities=traj.velocities.astype(np.float64),
        radii=traj.radii.astype(np.float64),
        ids=traj.ids.astype(np.int32),
        times=traj.times.astype(np.float32),
    )
    dtypes = [getattr(cast, name).dtype for name in _ARRAYS]
    assert dtypes == [np.float32, np.float32, np.float32, np.int64, np.float64]


def test_properties_report_sizes_spacing_and_presence():
    traj = _trajectory(num_frames=6, num_particles=7)
    summary = (traj.num_frames, traj.num_particles, traj.frame_dt, traj.present.shape)
    assert summary == (6, 7, pytest.approx(2.5e-3), (6, 7))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("positions", np.zeros((6, 7, 2)), r"positions: expected shape \[T, N, 3\]"),
        ("positions", np.zeros((6, 7)), r"positions: expected shape \[T, N, 3\]"),
        ("velocities", np.zeros((6, 8, 3)), "velocities: expected the shape of positions"),
        ("radii", np.ones(8), r"radii: expected shape \[N\]"),
        ("ids", np.arange(6), r"ids: expected shape \[N\]"),
        ("ids", np.array([1, 2, 3, 3, 4, 5, 6]), "ids: must be strictly ascending"),
        ("ids", np.array([1.5, 2, 3, 4, 5, 6, 7]), "ids: must be whole numbers"),
        ("times", np.arange(5.0), r"times: expected shape \[T\]"),
        ("times", np.array([0.0, 1, 2, 2, 3, 4]), "times: must be strictly increasing"),
        ("radii", np.zeros(7), "radii: every radius must be finite and positive"),
    ],
)
def test_bad_inputs_name_the_field(field, value, message):
    traj = _trajectory()
    kwargs = {name: getattr(traj, name) for name in _ARRAYS}
    kwargs[field] = value
    with pytest.raises(InputError, match=message):
        Trajectory(**kwargs)


def test_written_file_has_the_usual_permissions(tmp_path):
    write_trajectory(_trajectory(), tmp_path / "t.h5")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "t.h5").stat().st_mode & 0o777 == 0o666 & ~umask


def test_uneven_frames_are_refused_by_rollouts_and_training_windows():
    import dataclasses

    from granular_pyg.data import WindowDataset
    from granular_pyg.inference import load_simulator, rollout_trajectory
    from granular_pyg.io import read_trajectory
    from granular_pyg.samples import sample_files

    truth = read_trajectory(sample_files("hopper", "test")[0])
    truth.check_even_spacing()  # the bundled sample is even
    keep = np.delete(np.arange(truth.num_frames), 30)  # frame 30 dropped
    gap = dataclasses.replace(
        truth,
        positions=truth.positions[keep],
        velocities=truth.velocities[keep],
        times=truth.times[keep],
    )
    with pytest.raises(InputError, match=r"frame 30 \(t = 0.0775 s\) follows frame 29 after 0.005"):
        gap.check_even_spacing()
    sim, _ = load_simulator("pretrained:hopper")
    with pytest.raises(InputError, match="not evenly spaced"):
        rollout_trajectory(sim, gap, steps=1, progress=False)
    with pytest.raises(InputError, match="not evenly spaced"):
        WindowDataset([gap], history=5, frames_per_step=1)
