"""Run LIGGGHTS on a Scene: render the input script, run it with a progress bar, read the result.

The script uses settings that the Debian LIGGGHTS-PUBLIC package runs reliably: SI units, granular
atoms, Hertz contacts with tangential history, ASCII STL walls in ONE ``wall/gran`` fix (a
removed wall is dropped by re-creating that fix), ``insert/rate/region`` filling (which ignores
walls, so the inserted count is checked), ``boundary f f f`` with lost atoms ignored so that the
box floor is the outflow plane.

Phases: fill and settle for ``scene.settle_time`` (not recorded), then ``reset_timestep 0`` and
record a frame every ``scene.frame_dt`` for ``scene.duration``, splitting the run at every wall
event (a removal, or the start or stop of a motion).

Wall motions map onto ``fix move/mesh`` styles: ``rotation`` -> ``rotate``, ``translation`` ->
``linear``, ``oscillation`` -> ``wiggle``. A motion fix is created at the motion's start time
and unfixed at its stop time (or just before its wall is removed); an unfixed mesh keeps the pose
it reached; a rotation's reversal unfixes it and creates it again turning the other way.
Measured with ``dump mesh/stl`` (LIGGGHTS 3.8.0, ``tests/scenes/test_mesh_scene.py``): the mesh
follows :meth:`~granular_pyg.scenes.WallMotion.pose` across run splits, stops and reversals;
``linear`` and ``rotate`` to round-off, ``wiggle`` within ``amplitude * 2 pi / period * dem_dt``
(LIGGGHTS sums velocity x step, a half-step phase lead: 1.9e-5 m for 2 mm at 75 Hz).

Particle sizes: one ``particletemplate/sphere`` per radius and a
``particledistribution/discrete/numberbased`` over them (a single radius keeps the historical
``particledistribution/discrete`` line). The insertion region is a ``block`` or a ``cylinder z``.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from tqdm.auto import tqdm

from granular_pyg.errors import InputError
from granular_pyg.io import atomic_write
from granular_pyg.progress import show_progress
from granular_pyg.scenes import ParticleSpec, Scene, Wall
from granular_pyg.scenes.wall_angles import check_wall_for_liggghts

__all__ = [
    "DemRun",
    "LiggghtsError",
    "check_wall_for_liggghts",
    "find_liggghts",
    "prime_seeds",
    "render_input",
    "run_liggghts",
]

INSTALL_HINT = "apt-get install -y --no-install-recommends liggghts"
#: Environment variable that names the LIGGGHTS binary (a path or a name on PATH).
LIGGGHTS_ENV = "GRANULAR_PYG_LIGGGHTS"
DUMP_NAME = "traj.dump"
#: Particles enter the fill region moving along gravity at this speed (m/s), so that each
#: batch clears the region before the next.
INSERT_SPEED = 1.0
_THERMO = re.compile(r"^\s*(\d+)\s+(\d+)\s+\S+\s*$")


class LiggghtsError(RuntimeError):
    """LIGGGHTS failed; the message carries LIGGGHTS's own error text and the log's path."""


@dataclass
class DemRun:
    """A finished LIGGGHTS run.

    Attributes:
        workdir: folder with the script, STL files, log and dump.
        dump_path: the ``dump custom`` file of the recorded frames.
        version: LIGGGHTS's version line.
        wall_time_s: wall time of the ``liggghts`` process (s).
        inserted: particles present after filling and settling.
        conversion_time_s: time (s) spent turning the dump into a trajectory, once done.
    """

    workdir: Path
    dump_path: Path
    version: str
    wall_time_s: float
    inserted: int
    conversion_time_s: float = 0.0


def find_liggghts(executable: str | None = None) -> str:
    """Path of the LIGGGHTS binary: ``executable`` (a name on PATH or a path), else the
    ``GRANULAR_PYG_LIGGGHTS`` environment variable, else ``liggghts``; or an
    :class:`InputError` that says how to install it or where to point."""
    executable = executable or os.environ.get(LIGGGHTS_ENV) or "liggghts"
    found = shutil.which(executable)
    if found is None:
        raise InputError(
            f"LIGGGHTS ({executable!r}) is not found; install it with `{INSTALL_HINT}` "
            f"(as root; `make setup` does this), or give the binary's path: liggghts=<path> "
            f"(generate) or the environment variable {LIGGGHTS_ENV}=<path>"
        )
    return found


def _is_prime(n: int) -> bool:
    return n > 1 and all(n % k for k in range(2, math.isqrt(n) + 1))


def prime_seeds(seed: int, count: int = 3) -> list[int]:
    """``count`` distinct primes above 10000 derived from ``seed`` (LIGGGHTS needs such seeds)."""
    rng = np.random.default_rng(seed)
    primes: list[int] = []
    while len(primes) < count:
        n = int(rng.integers(10_007, 10_000_000))
        while not _is_prime(n):
            n += 1
        if n not in primes:
            primes.append(n)
    return primes


def _check_scene(scene: Scene) -> None:
    lo, hi = np.asarray(scene.domain_lo), np.asarray(scene.domain_hi)
    for wall in scene.walls:
        check_wall_for_liggghts(wall)
        vlo, vhi = wall.swept_bounds(scene.duration)
        if (vlo < lo - 1e-12).any() or (vhi > hi + 1e-12).any():
            raise InputError(
                f"wall {wall.name} leaves the simulation box {scene.domain_lo}..{scene.domain_hi}; "
                "LIGGGHTS needs every mesh inside it: enlarge domain_lo/domain_hi"
            )
    p = scene.particles
    if np.any(np.asarray(p.fill_lo) >= np.asarray(p.fill_hi)):
        raise InputError(f"fill region {p.fill_lo}..{p.fill_hi} is empty")


def write_ascii_stl(wall: Wall, path: Path) -> None:
    """The wall's mesh frame as an ASCII STL (LIGGGHTS cannot read binary STL)."""
    mesh = trimesh.Trimesh(wall.vertices, wall.faces, process=False)
    with atomic_write(path, "wb") as fh:
        fh.write(mesh.export(file_type="stl_ascii").encode())


def _steps(t: float, dt: float) -> int:
    return round(t / dt)


def _insertion(scene: Scene) -> tuple[float, int]:
    """Particle rate (1/s) and steps between insertions: the fill takes ~40% of the settle
    time, in batches of at most 15% of the fill box's volume."""
    p, dt = scene.particles, scene.dem_dt
    fill_volume = p.fill_volume
    particle_volume = 4.0 / 3.0 * math.pi * p.radius**3 if p.radii is None else p.mean_volume
    batch_max = max(1, int(0.15 * fill_volume / particle_volume))
    fill_time = 0.4 * scene.settle_time
    batches = max(1, math.ceil(p.count / batch_max))
    every = max(1, _steps(fill_time / batches, dt))
    rate = p.count / (batches * every * dt) * (1 + 1e-9)
    return rate, every


def _wall_fix(scene: Scene, t: float) -> list[str]:
    """``wall/gran`` over the walls present at recorded time ``t``."""
    rolling = " rolling_friction cdt" if scene.materials.rolling_friction > 0 else ""
    present = [f"wall_{w.name}" for w in scene.walls if w.present(t)]
    if not present:
        return []
    return [
        f"fix walls all wall/gran model hertz tangential history{rolling} mesh "
        f"n_meshes {len(present)} meshes {' '.join(present)}"
    ]


def _move_style(wall: Wall, sense: float = 1.0) -> str | None:
    """The ``fix move/mesh`` style and arguments of the wall's motion (a rotation turned the
    other way for ``sense = -1``); None if it never moves."""
    m = wall.motion
    if m.kind == "rotation" and m.omega != 0.0:
        axis = np.asarray(m.axis, float) * np.sign(m.omega) * sense
        period = 2 * math.pi / abs(m.omega)
        return f"rotate origin {_fmt(m.origin)} axis {_fmt(axis)} period {period!r}"
    if m.kind == "translation" and any(m.velocity):
        return f"linear {_fmt(m.velocity)}"
    if m.kind == "oscillation" and any(m.amplitude):
        return f"wiggle amplitude {_fmt(m.amplitude)} period {float(m.period)!r}"
    return None


def _move_fix(wall: Wall, sense: float = 1.0) -> str:
    """The ``fix move/mesh`` command that moves ``wall`` (turning the other way for
    ``sense = -1``)."""
    return f"fix move_{wall.name} all move/mesh mesh wall_{wall.name} {_move_style(wall, sense)}"


def _events(scene: Scene) -> list[tuple[float, list[str]]]:
    """Wall events in recorded time, each with the commands that enact it.

    At one time: motions stop, then motions start, then walls are removed (a moving wall's
    motion fix is unfixed before its mesh) and the wall fix is re-created.
    """
    stops: dict[float, list[str]] = {}
    starts: dict[float, list[str]] = {}
    removals: dict[float, list[str]] = {}
    for wall in scene.walls:
        if _move_style(wall) is None:
            continue
        m, gone = wall.motion, wall.removal_time
        start = max(0.0, m.start_time)
        if gone is not None and start >= gone:
            continue  # removed before it would move
        starts.setdefault(start, []).append(_move_fix(wall))
        stop = m.stop_time
        if gone is not None and (stop is None or stop > gone):
            stop = gone
        if stop is not None and stop < scene.duration:
            stops.setdefault(stop, []).append(f"unfix move_{wall.name}")
        # A reversal: the fix is replaced by one turning the other way from the pose reached.
        end = scene.duration if stop is None else min(stop, scene.duration)
        for k, flip in enumerate(t for t in m.reverse_times if t < end):
            stops.setdefault(flip, []).append(f"unfix move_{wall.name}")
            starts.setdefault(flip, []).append(_move_fix(wall, -1.0 if k % 2 == 0 else 1.0))
    for wall in scene.walls:
        if wall.removal_time is not None:
            removals.setdefault(wall.removal_time, []).extend(
                ["unfix walls", f"unfix wall_{wall.name}"]
            )
    events: dict[float, list[str]] = {}
    for t in sorted(set(stops) | set(starts) | set(removals)):
        events[t] = stops.get(t, []) + starts.get(t, []) + removals.get(t, [])
        # Re-create the single wall fix after any removal at that time.
        if t in removals:
            events[t] += _wall_fix(scene, t)
    return sorted(events.items())


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _particle_lines(
    p: ParticleSpec, density: float, template_seeds: list[int], distribution_seed: int
) -> list[str]:
    """Templates ``pts`` (``pts_2``, ...), the distribution ``pdd`` and the region ``fill``."""
    radii, fractions = p.size_distribution
    names = ["pts", *(f"pts_{k}" for k in range(2, len(radii) + 1))]
    lines = [
        f"fix {name} all particletemplate/sphere {seed} atom_type 1 density constant "
        f"{density!r} radius constant {r!r}"
        for name, seed, r in zip(names, template_seeds, radii, strict=True)
    ]
    if p.radii is None:
        lines.append(f"fix pdd all particledistribution/discrete {distribution_seed} 1 pts 1.0")
    else:
        pairs = " ".join(f"{n} {f!r}" for n, f in zip(names, fractions, strict=True))
        lines.append(
            f"fix pdd all particledistribution/discrete/numberbased {distribution_seed} "
            f"{len(radii)} {pairs}"
        )
    if p.fill_shape == "cylinder":
        cx, cy, r, z_lo, z_hi = p.cylinder
        lines.append(f"region fill cylinder z {_fmt((cx, cy, r, z_lo, z_hi))} units box")
    else:
        lines.append(
            f"region fill block {_fmt(np.ravel(np.stack([p.fill_lo, p.fill_hi], 1)))} units box"
        )
    return lines


def render_input(scene: Scene, seed: int, thermo_every: int | None = None) -> str:
    """The LIGGGHTS input script for ``scene`` (expects ``<wall>.stl`` beside it).

    Args:
        scene: the set-up.
        seed: base seed; LIGGGHTS's prime seeds derive from it (same seed, same run).
        thermo_every: steps between progress lines; about 400 lines per run by default.
    """
    m, p, dt = scene.materials, scene.particles, scene.dem_dt
    settle_steps = _steps(scene.settle_time, dt)
    record_steps = _steps(scene.duration, dt)
    frame_steps = _steps(scene.frame_dt, dt)
    thermo_every = thermo_every or max(1, (settle_steps + record_steps) // 400)
    num_sizes = len(p.size_distribution[0])
    s_template, s_distribution, s_insert, *s_more = prime_seeds(seed, 2 + num_sizes)
    rate, every = _insertion(scene)
    g = np.asarray(scene.gravity, float)
    g_norm = float(np.linalg.norm(g))
    g_unit = g / max(g_norm, 1e-300)
    rolling = " rolling_friction cdt" if m.rolling_friction > 0 else ""
    lo, hi = scene.domain_lo, scene.domain_hi
    lines = [
        f"# granular_pyg: scene {scene.name}, seed {seed}",
        "atom_style granular",
        "atom_modify map array",
        "boundary f f f",
        "newton off",
        "communicate single vel yes",
        "units si",
        f"region domain block {_fmt(np.ravel(np.stack([lo, hi], 1)))} units box",
        "create_box 1 domain",
        f"neighbor {p.radius!r} bin",
        "neigh_modify delay 0",
        f"fix m1 all property/global youngsModulus peratomtype {m.youngs_modulus!r}",
        f"fix m2 all property/global poissonsRatio peratomtype {m.poisson_ratio!r}",
        f"fix m3 all property/global coefficientRestitution peratomtypepair 1 {m.restitution!r}",
        f"fix m4 all property/global coefficientFriction peratomtypepair 1 {m.friction!r}",
    ]
    if m.rolling_friction > 0:
        lines.append(
            "fix m5 all property/global coefficientRollingFriction peratomtypepair 1 "
            f"{m.rolling_friction!r}"
        )
    lines += [
        f"pair_style gran model hertz tangential history{rolling}",
        "pair_coeff * *",
        f"timestep {dt!r}",
        f"fix gravi all gravity {g_norm!r} vector {_fmt(g_unit)}",
    ]
    lines += [f"fix wall_{w.name} all mesh/surface file {w.name}.stl type 1" for w in scene.walls]
    lines += _wall_fix(scene, 0.0)
    lines += _particle_lines(p, m.density, [s_template, *s_more], s_distribution)
    lines += [
        f"fix ins all insert/rate/region seed {s_insert} distributiontemplate pdd "
        f"nparticles {p.count} particlerate {rate!r} insert_every {every} "
        f"overlapcheck yes all_in yes vel constant {_fmt(INSERT_SPEED * g_unit)} region fill",
        "fix integr all nve/sphere",
        "compute_modify thermo_temp dynamic yes",
        "thermo_style custom step atoms ke",
        f"thermo {thermo_every}",
        "thermo_modify lost ignore norm no",
        'print "GPYG_PHASE settle"',
        f"run {settle_steps}",
        "unfix ins",
        "variable gpyg_count equal atoms",
        'print "GPYG_COUNT ${gpyg_count}"',
        "reset_timestep 0",
        f"dump dmp all custom {frame_steps} {DUMP_NAME} id type x y z vx vy vz radius",
        "dump_modify dmp sort id",
        'print "GPYG_PHASE record"',
    ]
    done = 0
    for t, cmds in _events(scene):
        step = min(_steps(t, dt), record_steps)
        if step > done:
            lines.append(f"run {step - done}")
            done = step
        lines += cmds
    if record_steps > done:
        lines.append(f"run {record_steps - done}")
    return "\n".join(lines) + "\n"


def run_liggghts(
    scene: Scene,
    workdir: str | os.PathLike,
    seed: int,
    *,
    mpi_procs: int = 1,
    executable: str | None = None,
    progress: bool = True,
    progress_position: int = 0,
) -> DemRun:
    """Write the STL files and script into ``workdir`` and run LIGGGHTS there.

    Shows a progress bar of simulated time (fill + recording). Stops early with
    :class:`InputError` if fewer particles than requested were inserted (insertion ignores
    walls: the fill region must be inside them and large enough).

    Args:
        scene: the set-up; its walls are checked (angles, box) before LIGGGHTS starts.
        workdir: folder for the run's files (created).
        seed: base seed (prime seeds derive from it).
        mpi_procs: MPI processes (``mpirun``); 1 runs serially, which is bit-reproducible.
        executable: LIGGGHTS binary name or path (default: see :func:`find_liggghts`).
        progress: show a tqdm bar.
        progress_position: tqdm line, for several runs at once.

    Raises:
        InputError: LIGGGHTS missing, bad wall triangle, short fill.
        LiggghtsError: LIGGGHTS reported an error (its text is in the message).
    """
    binary = find_liggghts(executable)
    _check_scene(scene)
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    for wall in scene.walls:
        write_ascii_stl(wall, workdir / f"{wall.name}.stl")
    with atomic_write(workdir / "in.liggghts") as fh:
        fh.write(render_input(scene, seed))
    (workdir / DUMP_NAME).unlink(missing_ok=True)

    cmd = [binary, "-in", "in.liggghts", "-log", "log.liggghts"]
    if mpi_procs > 1:
        mpirun = shutil.which("mpirun")
        if mpirun is None:
            raise InputError("mpi_procs > 1 needs `mpirun` (Debian package openmpi-bin)")
        cmd = [mpirun, "--allow-run-as-root", "-np", str(mpi_procs), *cmd]
    if shutil.which("stdbuf"):
        cmd = ["stdbuf", "-oL", "-eL", *cmd]  # without it an error's message can be lost

    total = scene.settle_time + scene.duration
    bar = tqdm(
        total=round(total, 6),
        unit="s",
        desc=f"LIGGGHTS {scene.name} (simulated time)",
        disable=not show_progress(progress),
        position=progress_position,
        leave=progress_position == 0,
        bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s [{elapsed}<{remaining}]",
    )
    version, inserted, offset, tail = "unknown", -1, 0.0, []
    start = time.perf_counter()
    with (
        (workdir / "screen.txt").open("w") as screen,
        subprocess.Popen(
            cmd,
            cwd=workdir,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            encoding="utf-8",
            errors="replace",
        ) as proc,
    ):
        assert proc.stdout is not None
        for line in proc.stdout:
            screen.write(line)
            tail = [*tail[-39:], line.rstrip()]
            if line.startswith("LIGGGHTS (Version"):
                version = line.strip()
            elif line.startswith("GPYG_PHASE record"):
                offset = scene.settle_time
            elif line.startswith("GPYG_COUNT"):
                inserted = int(float(line.split()[1]))
                if inserted != scene.particles.count:
                    proc.kill()
                    bar.close()
                    raise InputError(
                        f"LIGGGHTS inserted {inserted} of {scene.particles.count} particles "
                        f"(scene {scene.name}): insertion ignores walls, so the fill region "
                        f"{scene.particles.fill_lo}..{scene.particles.fill_hi} must lie inside "
                        "them and hold the particles; enlarge it, lower the count or lengthen "
                        f"settle_time. Log: {workdir / 'screen.txt'}"
                    )
            elif match := _THERMO.match(line):
                now = offset + int(match.group(1)) * scene.dem_dt
                bar.update(max(0.0, min(now, total) - bar.n))
        returncode = proc.wait()
    wall_time = time.perf_counter() - start
    bar.close()
    errors = [line for line in tail if "ERROR" in line]
    if returncode != 0 or errors:
        detail = "\n".join(errors or tail[-15:])
        raise LiggghtsError(
            f"LIGGGHTS failed (exit code {returncode}) in {workdir}:\n{detail}\n"
            f"Full output: {workdir / 'screen.txt'}"
        )
    dump = workdir / DUMP_NAME
    if not dump.exists():
        raise LiggghtsError(f"LIGGGHTS finished but wrote no dump in {workdir}")
    return DemRun(workdir, dump, version, wall_time, inserted)
