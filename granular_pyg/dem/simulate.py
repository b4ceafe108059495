"""Scene -> LIGGGHTS -> Trajectory, the ground-truth path in one call."""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from pathlib import Path

from granular_pyg.dem.dump import frames_to_arrays, read_dump
from granular_pyg.dem.liggghts import DemRun, LiggghtsError, run_liggghts
from granular_pyg.io import Trajectory
from granular_pyg.scenes import Scene

__all__ = ["simulate"]


def simulate(
    scene: Scene,
    seed: int,
    workdir: str | Path | None = None,
    *,
    keep_workdir: bool = False,
    mpi_procs: int = 1,
    progress: bool = True,
    progress_position: int = 0,
    executable: str | None = None,
) -> tuple[Trajectory, DemRun]:
    """Run LIGGGHTS on ``scene`` and convert its dump into a :class:`Trajectory`.

    Args:
        scene: the set-up.
        seed: base seed of the run (LIGGGHTS's prime seeds derive from it).
        workdir: folder for LIGGGHTS's files; a temporary one when omitted.
        keep_workdir: keep the folder (script, STL, log, dump) after success.
        mpi_procs, progress, progress_position, executable: see :func:`run_liggghts`.

    Returns:
        The trajectory (frames every ``scene.frame_dt`` from recorded time 0, NaN for particles
        that have left through the outflow) and the run's record (timings, version).
    """
    made_tmp = workdir is None
    workdir = Path(tempfile.mkdtemp(prefix="liggghts_") if made_tmp else workdir)
    run = run_liggghts(
        scene,
        workdir,
        seed,
        mpi_procs=mpi_procs,
        progress=progress,
        progress_position=progress_position,
        executable=executable,
    )
    start = time.perf_counter()
    arrays = frames_to_arrays(read_dump(run.dump_path, on_truncated="raise"), scene.dem_dt)
    if len(arrays["times"]) != scene.num_frames:
        raise LiggghtsError(
            f"LIGGGHTS wrote {len(arrays['times'])} frames, expected {scene.num_frames}: "
            f"see {workdir / 'screen.txt'}"
        )
    metadata = {
        "source": "liggghts",
        "seed": int(seed),
        "liggghts_version": run.version,
        "scene_params": scene.params,
        "materials": dataclasses.asdict(scene.materials),
        "mpi_procs": mpi_procs,
    }
    traj = Trajectory(
        positions=arrays["positions"],
        velocities=arrays["velocities"],
        radii=arrays["radii"],
        ids=arrays["ids"],
        times=arrays["times"],
        scene=scene,
        metadata=metadata,
    )
    # Timings stay in the run record (and generate's log), not in the file: a trajectory
    # regenerated from its config and seed is then the same file, byte for byte.
    run.conversion_time_s = time.perf_counter() - start
    if not keep_workdir:
        shutil.rmtree(workdir, ignore_errors=True)
    return traj, run
