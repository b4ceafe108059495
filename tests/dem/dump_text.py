"""Hand-made LIGGGHTS ``dump custom`` and mesh-dump files for the import tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

COLUMNS = "id type x y z vx vy vz radius"
BOX = ((-0.05, 0.05), (-0.05, 0.05), (-0.05, 0.2))


def frame_text(
    timestep: int,
    ids,
    positions,
    velocities,
    radius: float = 0.001,
    box=BOX,
) -> str:
    """One ``dump custom`` frame; ``positions``/``velocities`` ``[n, 3]``, values written with
    ``repr`` (so NaN/Inf come out as ``nan``/``inf``)."""
    lines = [
        "ITEM: TIMESTEP",
        str(timestep),
        "ITEM: NUMBER OF ATOMS",
        str(len(ids)),
        "ITEM: BOX BOUNDS ff ff ff",
        *(f"{lo!r} {hi!r}" for lo, hi in box),
        f"ITEM: ATOMS {COLUMNS}",
    ]
    for i, p, v in zip(ids, positions, velocities, strict=True):
        values = [*map(float, p), *map(float, v), radius]
        lines.append(f"{int(i)} 1 " + " ".join(repr(x) for x in values))
    return "\n".join(lines) + "\n"


def falling(
    timesteps,
    n: int = 20,
    dem_dt: float = 2e-5,
    g: float = 9.81,
    seed: int = 0,
) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """``(timestep, ids [n], positions [n, 3], velocities [n, 3])`` of ``n`` particles in free
    fall (exact: ``z = z0 + v0 t - g t^2 / 2``), time ``timestep * dem_dt``."""
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(-0.03, 0.03, (n, 3)) + np.array([0.0, 0.0, 0.1])
    v0 = rng.uniform(-0.2, 0.2, (n, 3))
    acc = np.array([0.0, 0.0, -g])
    out = []
    for step in timesteps:
        t = step * dem_dt
        out.append((step, np.arange(1, n + 1), x0 + v0 * t + 0.5 * acc * t**2, v0 + acc * t))
    return out


def write_dump(path: Path, frames, **kwargs) -> Path:
    """Write ``frames`` (as from :func:`falling`) as one multi-frame dump file."""
    path.write_text("".join(frame_text(s, i, p, v, **kwargs) for s, i, p, v in frames))
    return path


def plate(z: float = 0.0, half: float = 0.04) -> trimesh.Trimesh:
    """A square plate at height ``z`` (m), 2 triangles."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def write_stl(path: Path, mesh: trimesh.Trimesh) -> Path:
    """An ASCII STL file of ``mesh``."""
    path.write_text(mesh.export(file_type="stl_ascii"))
    return path


def write_mesh_dump(path: Path, triangles: np.ndarray) -> Path:
    """A ``dump mesh/stl`` file as LIGGGHTS writes it (6 significant digits) of ``triangles
    [F, 3, 3]``."""
    lines = ["solid LIGGGHTS_STL_EXPORT"]
    for tri in triangles:
        lines += ["  facet normal 0 0 1", "    outer loop"]
        lines += [f"      vertex {x:g} {y:g} {z:g}" for x, y, z in tri]
        lines += ["    endloop", "  endfacet"]
    lines.append("endsolid LIGGGHTS_STL_EXPORT")
    path.write_text("\n".join(lines) + "\n")
    return path
