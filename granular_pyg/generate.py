"""``python -m granular_pyg.generate scene=hopper n=30 out=data/hopper``: a LIGGGHTS dataset.

Writes ``<out>/traj_0000.h5 ...`` (one :class:`~granular_pyg.io.Trajectory` each) and
``<out>/manifest.json`` (scene config, per-trajectory parameters and seeds, train/valid/test
splits by trajectory, timings). Trajectory ``i`` draws its parameters (from the scene config's
``ranges``) and its LIGGGHTS seed from ``(seed, i)`` alone, so a run is reproducible and
resumable: finished files are skipped, and an interrupted trajectory leaves no file (writes are
atomic). ``jobs`` serial LIGGGHTS runs go at a time.
"""

from __future__ import annotations

import contextlib
import copy
import fcntl
import hashlib
import json
import os
import queue
import shutil
import sys
import tempfile
import time
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from granular_pyg.cli import EXIT_INPUT_ERROR, command
from granular_pyg.config import flatten
from granular_pyg.dem.liggghts import find_liggghts
from granular_pyg.dem.simulate import simulate
from granular_pyg.errors import InputError
from granular_pyg.io import atomic_write, read_trajectory, write_trajectory
from granular_pyg.progress import show_progress

__all__ = ["generate", "plan_trajectories", "split_counts", "splits_are_counts"]


def split_counts(n: int, splits: dict[str, float]) -> dict[str, int]:
    """Trajectories per split.

    ``splits`` holds either counts or fractions of ``n``:

    - counts, when every value is a whole number written without a decimal point
      (``{train: 2, valid: 1, test: 3}``): taken as they are; they must add up to ``n``
      (the command line sets ``n`` from them when ``n=`` is not given);
    - fractions otherwise (``{train: 0.8, valid: 0.1, test: 0.1}``): valid and test get
      ``round(n * f)`` (Python's rounding, half to even), at least one each when ``n >= 3``
      and their fraction is positive; train gets the rest.

    Raises:
        InputError: unknown split names, negative values, counts that do not add up to ``n``,
            or no training trajectory.
    """
    unknown = set(splits) - {"train", "valid", "test"}
    if unknown:
        raise InputError(f"splits: unknown splits {sorted(unknown)}; use train, valid and test")
    if any(float(v) < 0 for v in splits.values()):
        raise InputError(f"splits: {dict(splits)} has a negative value")
    if splits_are_counts(splits):
        counts = {name: int(splits.get(name, 0)) for name in ("train", "valid", "test")}
        if sum(counts.values()) != n:
            raise InputError(
                f"splits: the counts {counts} add up to {sum(counts.values())} trajectories, "
                f"but n={n}; leave n= out (it follows the counts) or make them agree"
            )
    else:
        counts = {}
        for name in ("valid", "test"):
            f = float(splits.get(name, 0.0))
            counts[name] = max(1 if n >= 3 and f > 0 else 0, round(n * f))
        counts["train"] = n - counts["valid"] - counts["test"]
    if counts["train"] < 1:
        raise InputError(f"splits {dict(splits)} leave no training trajectory out of n={n}")
    return counts


def splits_are_counts(splits) -> bool:
    """Whether ``splits`` holds counts (every value an integer, not a float) rather than
    fractions."""
    values = list(splits.values())
    return bool(values) and all(isinstance(v, int) and not isinstance(v, bool) for v in values)


def _sample(rng: np.random.Generator, low, high):
    if isinstance(low, int) and isinstance(high, int):
        return int(rng.integers(low, high + 1))
    return float(rng.uniform(float(low), float(high)))


def plan_trajectories(cfg: DictConfig) -> list[dict[str, Any]]:
    """One entry per trajectory: file name, split, seed and the scene-builder parameters.

    ``scene.ranges`` maps a parameter to ``[low, high]``, sampled uniformly per trajectory
    (integers when both bounds are); a dotted key (``materials.friction``) reaches into a
    nested parameter."""
    build = OmegaConf.to_container(cfg.scene.build, resolve=True)
    ranges = cfg.scene.get("ranges")
    ranges = flatten(OmegaConf.to_container(ranges, resolve=True)) if ranges else {}
    known = {k for k in flatten(build) if not k.startswith("_")} | set(build)
    unknown = set(ranges) - known
    if unknown:
        raise InputError(
            f"scene.ranges: {sorted(unknown)} are not parameters of {build['_target_']}; "
            f"choose from {sorted(k for k in known if not k.startswith('_'))}"
        )
    counts = split_counts(int(cfg.n), cfg.splits)
    splits = ["train"] * counts["train"] + ["valid"] * counts["valid"] + ["test"] * counts["test"]
    plan = []
    for i, split in enumerate(splits):
        rng = np.random.default_rng([int(cfg.seed), i])
        params = copy.deepcopy(build)
        for key in sorted(ranges):
            low, high = ranges[key]
            *path, leaf = key.split(".")  # a dotted key reaches into a nested parameter
            node = params
            for part in path:
                node = node[part]
            node[leaf] = _sample(rng, low, high)
        plan.append(
            {
                "file": f"traj_{i:04d}.h5",
                "index": i,
                "split": split,
                "seed": int(rng.integers(1, 2**31 - 1)),
                "params": params,
            }
        )
    return plan


def _run_one(entry: dict, cfg: DictConfig, out: Path, slots: queue.Queue) -> dict[str, float]:
    slot = slots.get()
    try:
        start = time.perf_counter()
        scene = hydra.utils.instantiate(entry["params"], _convert_="all")
        workdir = out / ".work" / Path(entry["file"]).stem
        traj, run = simulate(
            scene,
            entry["seed"],
            workdir,
            keep_workdir=True,
            mpi_procs=int(cfg.mpi_procs),
            progress=bool(cfg.progress),
            progress_position=slot,
            executable=cfg.get("liggghts"),
        )
        traj.metadata |= {"split": entry["split"], "index": entry["index"]}
        write_trajectory(traj, out / entry["file"], level=int(cfg.compression_level))
        digest = trajectory_digest(traj)
        if not cfg.keep_workdirs:
            shutil.rmtree(workdir, ignore_errors=True)
        total = time.perf_counter() - start
        return {
            "liggghts_s": run.wall_time_s,
            "pipeline_s": total,
            "overhead": (total - run.wall_time_s) / run.wall_time_s,
            "liggghts_version": run.version,
            "sha256": digest,
        }
    finally:
        slots.put(slot)


def trajectory_digest(traj) -> str:
    """SHA-256 of a trajectory's arrays (times, positions, velocities, radii): the same for a
    bit-identical regeneration, whatever the HDF5 file's layout."""
    digest = hashlib.sha256()
    for array in (traj.times, traj.positions, traj.velocities, traj.radii):
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


#: Manifest keys that must match for a run to add to an existing dataset folder.
DATASET_KEYS = ("scene_config", "seed", "n", "split_fractions")


def _check_same_dataset(path: Path, manifest: dict) -> None:
    """Refuse to add to a folder whose manifest was made with other settings."""
    if not path.is_file():
        return
    old = json.loads(path.read_text())
    differ = []
    for key in DATASET_KEYS:
        if key not in old:  # a manifest from before the key was recorded
            continue
        a, b = flatten(old[key], key), flatten(manifest[key], key)
        changed = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        differ += [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in changed]
    if differ:
        raise InputError(
            f"out: {path.parent} holds a dataset made with other settings ("
            + "; ".join(differ[:8])
            + "); choose a new out= folder, or rerun with the same settings to complete it"
        )


def generate(cfg: DictConfig) -> Path:
    """Generate (or complete) the dataset described by ``cfg``; returns the manifest's path.

    The manifest is written first (then completed with timings and digests), so a folder
    always records the settings of its files: a run into a folder made with other settings is
    refused, and splits never move.
    """
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    with folder_lock(out):
        return _generate(cfg, out)


#: The lock file a run holds in its folder while it writes there.
LOCK_FILE = ".generate.lock"


@contextlib.contextmanager
def folder_lock(out: Path):
    """Hold an exclusive lock on ``out/.generate.lock`` (``flock``: released when the process
    ends, however it ends), so that two runs into one folder never share its LIGGGHTS work
    folders.

    Raises:
        InputError: another run holds it (naming its process id).
    """
    path = out / LOCK_FILE
    handle = open(path, "a+")  # noqa: SIM115 (held for the run)
    try:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            raise InputError(
                f"out: another generate (process {holder}) is writing into {out}; wait for it "
                "to finish (then rerun to complete the folder) or choose another out="
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        yield
    finally:
        handle.close()


def _backfill_digests(out: Path, recorded: dict) -> int:
    """Record the SHA-256 of each finished trajectory whose manifest entry has none (a run
    killed after writing the file, before the manifest); returns how many were added."""
    added = 0
    for file, entry in recorded.items():
        if entry.get("sha256") or not (out / file).is_file():
            continue
        entry["sha256"] = trajectory_digest(read_trajectory(out / file))
        added += 1
    return added


def _read_manifest(path: Path) -> dict:
    """The manifest at ``path`` ({} when there is none yet).

    Raises:
        InputError: a manifest that is not a JSON object (cut off, or edited).
    """
    if not path.is_file():
        return {}
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(
            f"out: {path} is not valid JSON ({exc.msg} at line {exc.lineno}); it was cut off "
            "or edited: restore it, or delete it and rerun the same command to rebuild it"
        ) from None
    if not isinstance(manifest, dict):
        raise InputError(f"out: {path} is not a dataset manifest (a JSON object); restore it")
    return manifest


def _check_scene(entry: dict) -> None:
    """Build a scene to run before any LIGGGHTS work: a scene with no particle, or a
    value its constructor refuses, is an error here rather than LIGGGHTS's."""
    scene = hydra.utils.instantiate(entry["params"], _convert_="all")
    if scene.particles.count < 1:
        raise InputError(
            f"scene.build.num_particles: {entry['file']} would hold {scene.particles.count} "
            "particles; a trajectory needs at least 1"
        )


def _generate(cfg: DictConfig, out: Path) -> Path:
    plan = plan_trajectories(cfg)
    path = out / "manifest.json"
    old = _read_manifest(path)
    recorded = {e["file"]: e for e in old.get("trajectories", [])}
    backfilled = _backfill_digests(out, recorded)
    if backfilled:
        print(f"recorded the SHA-256 of {backfilled} finished trajectories the manifest lacked")
    manifest = _manifest(cfg, plan, recorded)
    _check_same_dataset(path, manifest)
    with atomic_write(path) as fh:
        json.dump(manifest, fh, indent=1)
    todo = [e for e in plan if not (out / e["file"]).exists()]
    if todo:
        find_liggghts(cfg.get("liggghts"))  # before any work: a clear error if it is missing
        for entry in todo:
            _check_scene(entry)
    print(f"{cfg.scene.name}: {len(plan) - len(todo)} of {len(plan)} trajectories present in {out}")
    jobs = max(1, int(cfg.jobs))
    slots: queue.Queue = queue.Queue()
    for k in range(jobs):
        slots.put(k + 1)
    timings: dict[str, dict] = {}
    bar = tqdm(
        total=len(plan),
        initial=len(plan) - len(todo),
        desc="trajectories",
        position=0,
        disable=not show_progress(cfg.progress),
    )
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(_run_one, e, cfg, out, slots): e for e in todo}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_EXCEPTION)
            for fut in done:
                entry = futures[fut]
                if fut.exception() is not None:
                    for other in pending:
                        other.cancel()
                    raise RuntimeError(
                        f"trajectory {entry['file']} failed (parameters {entry['params']}); "
                        f"rerun the same command to resume: {fut.exception()}"
                    ) from fut.exception()
                timings[entry["file"]] = fut.result()
                bar.update(1)
    bar.close()

    changed = _changed_digests(recorded, timings)
    manifest = _manifest(cfg, plan, recorded, timings)
    with atomic_write(path) as fh:
        json.dump(manifest, fh, indent=1)
    if changed:
        raise InputError(
            f"out: {len(changed)} regenerated trajectories differ from the SHA-256 their "
            f"manifest recorded ({'; '.join(changed[:4])}): this LIGGGHTS build or machine "
            "does not reproduce the dataset bit for bit (the manifest keeps the recorded "
            "digests; the new files are kept for inspection)"
        )
    if not cfg.keep_workdirs:
        shutil.rmtree(out / ".work", ignore_errors=True)
    if timings:
        lig = sum(t["liggghts_s"] for t in timings.values())
        total = sum(t["pipeline_s"] for t in timings.values())
        overhead = 100 * (total - lig) / lig
        print(f"LIGGGHTS {lig:.1f} s, pipeline {total:.1f} s: overhead {overhead:.1f}%")
    print(f"manifest: {path}")
    return path


def _changed_digests(recorded: dict, timings: dict) -> list[str]:
    """``file: recorded -> new`` for each trajectory generated now whose digest differs from
    the one an earlier run recorded in the manifest."""
    changed = []
    for file, timing in sorted(timings.items()):
        before = (recorded.get(file) or {}).get("sha256")
        if before and timing.get("sha256") != before:
            changed.append(f"{file}: {before[:12]} -> {str(timing.get('sha256'))[:12]}")
    return changed


def _manifest(cfg: DictConfig, plan: list[dict], recorded: dict, timings: dict | None = None):
    """The manifest of ``plan``: settings, splits, and per trajectory its timing and digest
    (from this run, else as ``recorded`` by an earlier one)."""
    timings = timings or {}
    family = str(cfg.get("family") or cfg.scene.name)
    entries = []
    for e in plan:
        done = timings.get(e["file"]) or (recorded.get(e["file"]) or {}).get("timing")
        new_sha = (done or {}).pop("sha256", None)
        sha = (recorded.get(e["file"]) or {}).get("sha256") or new_sha  # the first one stays
        entries.append(e | {"family": family, "timing": done, "sha256": sha})
    return {
        "scene": cfg.scene.name,
        "family": family,
        "n": len(plan),
        "seed": int(cfg.seed),
        # As given: fractions (floats) or counts (integers).
        "split_fractions": {
            k: (int(v) if splits_are_counts(cfg.splits) else float(v))
            for k, v in cfg.splits.items()
        },
        "scene_config": OmegaConf.to_container(cfg.scene, resolve=True),
        "splits": {
            s: [e["file"] for e in plan if e["split"] == s] for s in ("train", "valid", "test")
        },
        "trajectories": entries,
    }


def _without_ranges_if_asked(cfg: DictConfig) -> DictConfig:
    """``scene.ranges={}`` on the command line means no ranges (Hydra would merge the empty
    dict into the preset's ranges and change nothing), as ``~scene.ranges`` and
    ``scene.ranges=null`` do."""
    try:
        overrides = HydraConfig.get().overrides.task
    except ValueError:  # not inside a Hydra app
        return cfg
    if any(o.replace(" ", "") in ("scene.ranges={}", "scene.ranges=") for o in overrides):
        OmegaConf.set_struct(cfg, False)
        cfg.scene.ranges = None
    return cfg


def _n_from_counts(cfg: DictConfig) -> DictConfig:
    """``splits`` given as counts without ``n=`` on the command line: ``n`` is their sum."""
    if not splits_are_counts(cfg.splits):
        return cfg
    try:
        overrides = HydraConfig.get().overrides.task
    except ValueError:  # not inside a Hydra app
        return cfg
    if not any(o.replace(" ", "").lstrip("+~").startswith("n=") for o in overrides):
        OmegaConf.set_struct(cfg, False)
        cfg.n = sum(int(v) for v in cfg.splits.values())
    return cfg


@command("generate")
def main(cfg: DictConfig) -> None:
    generate(_n_from_counts(_without_ranges_if_asked(cfg)))


def scene_file_arguments(argv: list[str]) -> list[str]:
    """``argv`` with ``scene=<a YAML file>`` (a path: it has a ``/`` or ends in ``.yaml``)
    turned into what Hydra understands: the file copied into a fresh config folder's ``scene/``
    and ``--config-dir=<that folder> scene=<its name>``, so a scene file anywhere (outside a
    checkout, with a wheel install) works. Names of shipped scenes (``scene=hopper``) pass
    unchanged.

    Raises:
        InputError: the path names no file.
    """
    out, extra = [], []
    for arg in argv:
        key, _, value = arg.partition("=")
        if key.lstrip("+") != "scene" or not ("/" in value or value.endswith((".yaml", ".yml"))):
            out.append(arg)
            continue
        path = Path(value).expanduser()
        if not path.is_file():
            raise InputError(
                f"scene: {value} is not a file; give an existing scene YAML (a copy of "
                "conf/scene/mesh.yaml) or the name of a shipped scene (scene=hopper)"
            )
        from granular_pyg.config import CONF_DIR

        shipped = (CONF_DIR / "scene" / f"{path.stem}.yaml").exists()
        name = f"{path.stem}_file" if shipped else path.stem  # the shipped one would win
        folder = Path(tempfile.mkdtemp(prefix="granular_pyg_scene_"))
        (folder / "scene").mkdir()
        shutil.copyfile(path, folder / "scene" / f"{name}.yaml")
        extra.append(f"--config-dir={folder}")
        out.append(f"{key}={name}")
    return extra + out


if __name__ == "__main__":
    try:
        sys.argv[1:] = scene_file_arguments(sys.argv[1:])
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(EXIT_INPUT_ERROR)
    main()
