"""ParaView output: particles and walls per frame as VTK PolyData (``.vtp``) with ``.pvd`` series.

Open ``<out>/all.pvd`` in ParaView (File > Open, Apply) to play ground truth and prediction
side by side: each trajectory gets its particles (points with ``velocity`` m/s, ``radius`` m and
``id``; render them with the *Point Gaussian* representation, scale array ``radius``) and its
walls (triangles at their pose at each frame; a removed wall, such as the hopper's lid after
``t_open``, is absent). Trajectory ``i`` is shifted by ``i * spacing`` along x so the two sit
next to each other; ``spacing=0`` overlays them. Each trajectory also gets its own
``<label>.pvd`` without the shift.

Files are VTK XML with inline base64 binary data (``format="binary"``, compact) or plain
``"ascii"``; :func:`read_vtp` reads either back. Every file is written atomically.
"""

from __future__ import annotations

import base64
import os
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from granular_pyg.errors import InputError
from granular_pyg.io.atomic import atomic_write
from granular_pyg.io.trajectory import Trajectory
from granular_pyg.progress import show_progress

__all__ = ["export_paraview", "read_vtp", "write_pvd", "write_vtp"]

_VTK_TYPES = {
    np.dtype(np.float32): "Float32",
    np.dtype(np.float64): "Float64",
    np.dtype(np.int32): "Int32",
    np.dtype(np.int64): "Int64",
    np.dtype(np.uint8): "UInt8",
}
_NP_TYPES = {name: dtype for dtype, name in _VTK_TYPES.items()}


def _data_array(parent: ET.Element, name: str, values: np.ndarray, fmt: str) -> None:
    values = np.ascontiguousarray(values)
    if values.dtype not in _VTK_TYPES:
        raise InputError(f"{name}: dtype {values.dtype} has no VTK type; use float32/64 or int")
    comps = 1 if values.ndim == 1 else values.shape[1]
    node = ET.SubElement(
        parent,
        "DataArray",
        type=_VTK_TYPES[values.dtype],
        Name=name,
        NumberOfComponents=str(comps),
        format=fmt,
    )
    if fmt == "ascii":
        node.text = " ".join(map(repr, values.ravel().tolist()))
    else:  # VTK's inline binary: base64 of a UInt32 byte count followed by the raw bytes
        raw = values.astype(values.dtype.newbyteorder("<")).tobytes()
        node.text = base64.b64encode(struct.pack("<I", len(raw)) + raw).decode("ascii")


def write_vtp(
    path: str | os.PathLike,
    points: np.ndarray,
    point_data: dict[str, np.ndarray] | None = None,
    triangles: np.ndarray | None = None,
    fmt: str = "binary",
) -> Path:
    """Write one VTK PolyData file: points as vertices, or a triangle surface.

    Args:
        path: the ``.vtp`` file.
        points: ``[N, 3]`` coordinates (m); non-finite rows are not allowed (drop them first).
        point_data: ``{name: [N] or [N, C]}`` arrays per point.
        triangles: ``[F, 3]`` point indices: a surface; None: every point is a vertex cell.
        fmt: ``"binary"`` (base64 inline) or ``"ascii"``.

    Returns:
        ``path`` as a Path.
    """
    if fmt not in ("binary", "ascii"):
        raise InputError(f"fmt: expected 'binary' or 'ascii', got {fmt!r}")
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points: expected shape [N, 3], got {list(points.shape)}")
    if not np.isfinite(points).all():
        raise InputError("points: contain NaN/Inf; drop particles that have left before writing")
    n = len(points)
    point_data = point_data or {}
    for name, values in point_data.items():
        if len(values) != n:
            raise InputError(f"point_data[{name!r}]: {len(values)} values for {n} points")
    root = ET.Element("VTKFile", type="PolyData", version="1.0", byte_order="LittleEndian")
    root.set("header_type", "UInt32")
    poly = ET.SubElement(ET.SubElement(root, "PolyData"), "Piece", NumberOfPoints=str(n))
    if triangles is None:
        cells, kind, per = np.arange(n, dtype=np.int64), "Verts", 1
    else:
        triangles = np.asarray(triangles, dtype=np.int64)
        if triangles.ndim != 2 or triangles.shape[1] != 3:
            raise InputError(f"triangles: expected shape [F, 3], got {list(triangles.shape)}")
        if triangles.size and (triangles.min() < 0 or triangles.max() >= n):
            raise InputError(f"triangles: indices must lie in [0, {n})")
        cells, kind, per = triangles.ravel(), "Polys", 3
    count = len(cells) // per
    for other in ("Verts", "Lines", "Strips", "Polys"):
        poly.set(f"NumberOf{other}", str(count if other == kind else 0))
    _data_array(ET.SubElement(poly, "Points"), "Points", points.astype(np.float32), fmt)
    data = ET.SubElement(poly, "PointData")
    for name, values in point_data.items():
        values = np.asarray(values)
        if values.dtype.kind == "f":
            values = values.astype(np.float32)
        elif values.dtype.kind in "iu":
            values = values.astype(np.int64)
        _data_array(data, name, values, fmt)
    cell_node = ET.SubElement(poly, kind)
    _data_array(cell_node, "connectivity", cells, fmt)
    _data_array(cell_node, "offsets", per * np.arange(1, count + 1, dtype=np.int64), fmt)
    with atomic_write(path, "wb") as fh:
        ET.ElementTree(root).write(fh, encoding="utf-8", xml_declaration=True)
    return Path(path)


def read_vtp(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a ``.vtp`` written by :func:`write_vtp`.

    Returns:
        ``{"points": [N, 3], "connectivity": [...], "offsets": [...], <point data>: ...}``.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"{path}: not a readable VTK XML file ({exc})") from exc
    out: dict[str, np.ndarray] = {}
    for node in root.iter("DataArray"):
        dtype = _NP_TYPES[node.get("type")]
        comps = int(node.get("NumberOfComponents", "1"))
        if node.get("format") == "ascii":
            values = np.array((node.text or "").split(), dtype=dtype)
        else:
            raw = base64.b64decode(node.text or "")
            size = struct.unpack("<I", raw[:4])[0]
            values = np.frombuffer(raw[4 : 4 + size], dtype=dtype.newbyteorder("<")).astype(dtype)
        name = node.get("Name")
        out["points" if name == "Points" else name] = (
            values.reshape(-1, comps) if comps > 1 else values
        )
    return out


def write_pvd(path: str | os.PathLike, entries: list[tuple[float, int, str]]) -> Path:
    """Write a ParaView collection: ``entries`` of ``(time s, part, file relative to path)``."""
    root = ET.Element("VTKFile", type="Collection", version="1.0", byte_order="LittleEndian")
    coll = ET.SubElement(root, "Collection")
    for time, part, file in entries:
        ET.SubElement(coll, "DataSet", timestep=repr(float(time)), part=str(part), file=file)
    with atomic_write(path, "wb") as fh:
        ET.ElementTree(root).write(fh, encoding="utf-8", xml_declaration=True)
    return Path(path)


def export_paraview(
    out: str | os.PathLike,
    trajectories: dict[str, Trajectory],
    every: int = 1,
    spacing: float | None = None,
    fmt: str = "binary",
    progress: bool = True,
) -> Path:
    """Write trajectories (e.g. ``{"truth": ..., "prediction": ...}``) for ParaView.

    Args:
        out: folder; gets ``<label>/particles_<frame>.vtp``, ``<label>/walls_<frame>.vtp``,
            ``<label>.pvd`` and ``all.pvd``.
        trajectories: label -> Trajectory; walls are written for those with a Scene.
        every: write every ``every``-th frame.
        spacing: x shift (m) between consecutive trajectories in ``all.pvd``; default 1.2 times
            the first scene's box width (or the particles' x extent); 0 overlays them.
        fmt: ``"binary"`` or ``"ascii"``.
        progress: show a progress bar.

    Returns:
        The path of ``all.pvd``.
    """
    if not trajectories:
        raise InputError("trajectories: nothing to export; pass at least one Trajectory")
    if every < 1:
        raise InputError(f"every: expected a positive frame stride, got {every}")
    out = Path(out)
    first = next(iter(trajectories.values()))
    if spacing is None:
        if first.scene is not None:
            spacing = 1.2 * (first.scene.domain_hi[0] - first.scene.domain_lo[0])
        else:
            x = first.positions[..., 0]
            spacing = 1.2 * float(np.nanmax(x) - np.nanmin(x)) if np.isfinite(x).any() else 1.0
    combined: list[tuple[float, int, str]] = []
    total = sum(len(range(0, t.num_frames, every)) for t in trajectories.values())
    bar = tqdm(
        total=total, desc="ParaView export", unit="frame", disable=not show_progress(progress)
    )
    for i, (label, traj) in enumerate(trajectories.items()):
        if not label.isidentifier():
            raise InputError(f"trajectories: label {label!r} must be a plain name (letters, _)")
        own: list[tuple[float, int, str]] = []
        shift = np.array([i * spacing, 0.0, 0.0])
        for f in range(0, traj.num_frames, every):
            t = float(traj.times[f])
            for part, (name, points, data, tris) in enumerate(_frame_parts(traj, f)):
                file = f"{label}/{name}_{f:06d}.vtp"
                write_vtp(out / file, points, data, tris, fmt)
                own.append((t, part, file))
                if i:  # the shifted copy for all.pvd
                    shifted = f"{label}/shifted/{name}_{f:06d}.vtp"
                    write_vtp(out / shifted, points + shift, data, tris, fmt)
                    file = shifted
                combined.append((t, 2 * i + part, file))
            bar.update()
        write_pvd(out / f"{label}.pvd", own)
    bar.close()
    return write_pvd(out / "all.pvd", combined)


def _frame_parts(traj: Trajectory, frame: int):
    """``(name, points, point_data, triangles)`` of the particles and walls of one frame."""
    present = np.isfinite(traj.positions[frame]).all(1)
    vel = traj.velocities[frame][present]
    data = {
        "velocity": np.nan_to_num(vel),
        "speed": np.nan_to_num(np.linalg.norm(vel, axis=1)),
        "radius": traj.radii[present],
        "id": traj.ids[present],
    }
    yield "particles", traj.positions[frame][present], data, None
    if traj.scene is None:
        return
    t = float(traj.times[frame])
    points, tris, wall_id, base = [], [], [], 0
    for w, wall in enumerate(traj.scene.walls):
        if not wall.present(t):
            continue
        vertices = wall.vertices_at(t)
        points.append(vertices)
        tris.append(np.asarray(wall.faces) + base)
        wall_id.append(np.full(len(vertices), w))
        base += len(vertices)
    if points:
        yield (
            "walls",
            np.concatenate(points),
            {"wall": np.concatenate(wall_id)},
            np.concatenate(tris),
        )
