r"""The example equipment shipped as STL files: ``python -m granular_pyg.scenes.example_meshes``.

Writes, deterministically (same bytes on every run), binary STL files in metres into
``granular_pyg/scenes/meshes/`` (or ``--out``); the configs ``conf/scene/mesh_cone.yaml``,
``mesh_pyramid.yaml``, ``mesh_silo.yaml`` and ``mesh_lifter_drum.yaml`` build scenes from them
with :func:`~granular_pyg.scenes.make_mesh_scene`. Gravity is along -z for the hoppers and the silo;
the drum's axis is y.

* ``cone_hopper.stl``: a conical hopper, 60 deg to the horizontal, from a circular orifice of
  radius 9 mm at z = 0 up to a cylindrical bin of radius 30 mm, open at the top (z = 0.1 m).
  ``cone_lid.stl``: the disc that closes the orifice (removed at ``t_open``)::

        |          |      <- z = 0.10 (open)
        |   bin    |
        \        /      <- z = 0.036
         \ cone /
          \____/        <- z = 0: orifice, closed by the lid

* ``pyramid_hopper.stl``: a pyramidal hopper whose four plane walls converge both ways onto a
  square outlet (20 mm a side, centred at (4 mm, 0) at z = 0), so that its walls stand at 57,
  61 and 66 deg to the horizontal; they rise to a square bin (64 mm a side, centred on the axis)
  at z = 0.04, open at the top (z = 0.1 m). ``pyramid_lid.stl``: the square that closes the
  outlet.
* ``silo.stl``: a flat-bottomed cylindrical silo (radius 35 mm, height 0.1 m, open top) whose
  floor has a circular outlet of radius 8 mm centred 15 mm off the axis, at (0.015, 0, 0).
  ``silo_lid.stl``: the disc that closes the outlet.
* ``drum_shell.stl``: a closed drum about the y axis (radius 45 mm, length 30 mm, end caps).
  ``drum_lifters.stl``: 4 rectangular lifter bars (6 mm tall, 4 mm wide, the drum's length)
  on the inner shell at 0, 90, 180 and 270 deg about y (on +x, +z, -x, -z at t = 0), each a
  closed box whose outer face lies flat on a shell facet; give both the same rotation.

Triangles are kept well-shaped (every angle far above LIGGGHTS's 0.256 deg limit, checked before
writing); each file stays below 100 kB.
"""

from __future__ import annotations

import argparse
import itertools
import math
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from granular_pyg.scenes.mesh_scene import MESH_DIR
from granular_pyg.scenes.scene import Wall
from granular_pyg.scenes.wall_angles import check_wall_for_liggghts

__all__ = ["MESH_DIR", "example_meshes", "main", "write_binary_stl"]

#: Fixed 80-byte header of every file written here (no dates: files are reproducible).
HEADER = b"granular_pyg example mesh, binary STL, metres".ljust(80, b" ")

#: Facets around every circle.
SECTIONS = 48


def write_binary_stl(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a binary STL: float32 unit normals (from the vertex order) and vertices.

    Args:
        path: the file.
        vertices: ``[V, 3]`` (m).
        faces: ``[F, 3]`` vertex indices, counter-clockwise seen from the normal's side.
    """
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.sqrt((normal**2).sum(1, keepdims=True))
    record = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    record["n"], record["v"] = normal, tri
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(HEADER + struct.pack("<I", len(tri)) + record.tobytes())


class _Builder:
    """Vertices and triangles accumulated part by part (float64, m)."""

    def __init__(self) -> None:
        self.vertices: list[tuple[float, float, float]] = []
        self.faces: list[tuple[int, int, int]] = []

    def add(self, points: Sequence[Sequence[float]]) -> list[int]:
        start = len(self.vertices)
        self.vertices += [tuple(float(c) for c in p) for p in points]
        return list(range(start, len(self.vertices)))

    def quad(self, a: int, b: int, c: int, d: int) -> None:
        """Quad ``a b c d`` (counter-clockwise seen from its normal), split along ``a-c``."""
        self.faces += [(a, b, c), (a, c, d)]

    def strip(self, lower: list[int], upper: list[int], closed: bool = True) -> None:
        """Quads between two rows of equal length; normals follow ``lower[i] -> lower[i+1] ->
        upper[i+1]``."""
        n = len(lower)
        for i in range(n if closed else n - 1):
            j = (i + 1) % n
            self.quad(lower[i], lower[j], upper[j], upper[i])

    def fan(self, centre: int, ring: list[int]) -> None:
        """Triangles ``centre, ring[i], ring[i+1]`` round a closed ring."""
        n = len(ring)
        self.faces += [(centre, ring[i], ring[(i + 1) % n]) for i in range(n)]

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.vertices, np.float64), np.array(self.faces, np.int64)


def _circle(cx: float, cy: float, radius: float, z: float, phase: float = 0.0) -> list:
    """``SECTIONS`` points on a horizontal circle, counter-clockwise seen from +z."""
    return [
        (
            cx + radius * math.cos(phase + 2 * math.pi * k / SECTIONS),
            cy + radius * math.sin(phase + 2 * math.pi * k / SECTIONS),
            z,
        )
        for k in range(SECTIONS)
    ]


def cone_hopper(
    orifice_radius: float = 0.009,
    bin_radius: float = 0.03,
    cone_angle_deg: float = 60.0,
    height: float = 0.1,
    element: float = 0.008,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The conical hopper (``cone_hopper``) and its orifice lid (``cone_lid``); normals point
    out of the particle space. Sizes in m, the cone's angle to the horizontal in degrees."""
    cone_top = (bin_radius - orifice_radius) * math.tan(math.radians(cone_angle_deg))
    slant = math.hypot(cone_top, bin_radius - orifice_radius)
    n_cone = math.ceil(slant / element)
    n_bin = math.ceil((height - cone_top) / element)
    hopper = _Builder()
    rows = []
    for i in range(n_cone + 1):
        f = i / n_cone
        r = orifice_radius + f * (bin_radius - orifice_radius)
        rows.append(hopper.add(_circle(0.0, 0.0, r, f * cone_top)))
    for i in range(1, n_bin + 1):
        z = cone_top + i / n_bin * (height - cone_top)
        rows.append(hopper.add(_circle(0.0, 0.0, bin_radius, z)))
    for lower, upper in itertools.pairwise(rows):
        hopper.strip(lower, upper)  # counter-clockwise rings: normals point outwards
    lid = _Builder()
    ring = lid.add(_circle(0.0, 0.0, orifice_radius, 0.0))
    centre = lid.add([(0.0, 0.0, 0.0)])[0]
    lid.fan(centre, ring[::-1])  # normal -z: out of the particle space
    return {"cone_hopper": hopper.arrays(), "cone_lid": lid.arrays()}


def _square(cx: float, half: float, z: float, per_side: int) -> list:
    """``4 per_side`` points round a horizontal square of half-width ``half`` centred at
    ``(cx, 0)``, counter-clockwise seen from +z, starting at its ``(-, -)`` corner."""
    corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
    points = []
    for (ax, ay), (bx, by) in zip(corners, corners[1:] + corners[:1], strict=True):
        for k in range(per_side):
            f = k / per_side
            points.append((cx + half * (ax + f * (bx - ax)), half * (ay + f * (by - ay)), z))
    return points


def pyramid_hopper(
    outlet_half: float = 0.01,
    outlet_offset: float = 0.004,
    bin_half: float = 0.032,
    bin_bottom: float = 0.04,
    height: float = 0.1,
    per_side: int = 4,
    element: float = 0.008,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The pyramidal hopper (``pyramid_hopper``) and its square outlet's lid (``pyramid_lid``);
    normals point out of the particle space. Sizes in m.

    Rings of ``4 per_side`` points join the outlet's square (centred at ``(outlet_offset, 0)``)
    to the bin's (centred on the axis) point for point, so each wall is a plane trapezoid of
    quads; the bin's vertical walls carry the same rings up to ``height``.
    """
    hopper = _Builder()
    bottom = np.array(_square(outlet_offset, outlet_half, 0.0, per_side))
    top = np.array(_square(0.0, bin_half, bin_bottom, per_side))
    slant = float(np.max(np.linalg.norm(top - bottom, axis=1)))
    n_slope = math.ceil(slant / element)
    n_bin = math.ceil((height - bin_bottom) / element)
    rows = [hopper.add(bottom + (top - bottom) * i / n_slope) for i in range(n_slope + 1)]
    for i in range(1, n_bin + 1):
        rise = np.array([0.0, 0.0, (height - bin_bottom) * i / n_bin])
        rows.append(hopper.add(top + rise))
    for lower, upper in itertools.pairwise(rows):
        hopper.strip(lower, upper)  # counter-clockwise rings: normals point outwards
    lid = _Builder()
    ring = lid.add(bottom)
    centre = lid.add([(outlet_offset, 0.0, 0.0)])[0]
    lid.fan(centre, ring[::-1])  # normal -z: out of the particle space
    return {"pyramid_hopper": hopper.arrays(), "pyramid_lid": lid.arrays()}


def silo(
    radius: float = 0.035,
    height: float = 0.1,
    outlet_radius: float = 0.008,
    outlet_offset: float = 0.015,
    floor_rows: int = 7,
    element: float = 0.01,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The flat-bottomed silo (``silo``) with an off-centre outlet at ``(outlet_offset, 0, 0)``
    and the outlet's lid (``silo_lid``); normals point out of the particle space.

    The floor is a structured grid between the outlet circle and the silo's circle: rays from
    the outlet's centre at ``SECTIONS`` even angles, ``floor_rows`` rows graded finer towards
    the outlet; the wall stands on the floor's outer points, so floor and wall share them.
    """
    cx = outlet_offset
    builder = _Builder()
    rows = []
    for j in range(floor_rows + 1):
        t = (j / floor_rows) ** 1.4  # finer rows near the outlet
        ring = []
        for k in range(SECTIONS):
            theta = 2 * math.pi * k / SECTIONS
            u = (math.cos(theta), math.sin(theta))
            cu = cx * u[0]
            reach = -cu + math.sqrt(cu * cu - cx * cx + radius * radius)  # to the silo wall
            rho = outlet_radius + t * (reach - outlet_radius)
            ring.append((cx + rho * u[0], rho * u[1], 0.0))
        rows.append(builder.add(ring))
    for inner, outer in itertools.pairwise(rows):
        builder.strip(inner, outer)  # floor normal -z
    outer = [builder.vertices[i] for i in rows[-1]]
    n_wall = math.ceil(height / element)
    wall_rows = [rows[-1]]
    for i in range(1, n_wall + 1):
        z = height * i / n_wall
        wall_rows.append(builder.add([(x, y, z) for x, y, _ in outer]))
    for lower, upper in itertools.pairwise(wall_rows):
        builder.strip(lower, upper)  # normals point outwards
    lid = _Builder()
    ring = lid.add([builder.vertices[i] for i in rows[0]])
    centre = lid.add([(cx, 0.0, 0.0)])[0]
    lid.fan(centre, ring[::-1])
    return {"silo": builder.arrays(), "silo_lid": lid.arrays()}


def lifter_drum(
    radius: float = 0.045,
    length: float = 0.03,
    lifter_height: float = 0.006,
    lifter_width: float = 0.004,
    length_rows: int = 3,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The closed drum about y (``drum_shell``, normals outwards) and its 4 lifter bars
    (``drum_lifters``, closed boxes, normals out of the bars)."""
    half = length / 2
    shell = _Builder()

    def ring(y: float) -> list:
        # Vertices at half steps, so that a facet is centred at 0, 90, 180 and 270 deg.
        return [
            (
                radius * math.cos(2 * math.pi * (k + 0.5) / SECTIONS),
                y,
                radius * math.sin(2 * math.pi * (k + 0.5) / SECTIONS),
            )
            for k in range(SECTIONS)
        ]

    rows = [shell.add(ring(-half + length * i / length_rows)) for i in range(length_rows + 1)]
    for lower, upper in itertools.pairwise(rows):
        shell.strip(upper, lower)  # counter-clockwise about -y seen from outside: outwards
    back = shell.add([(0.0, -half, 0.0)])[0]
    front = shell.add([(0.0, half, 0.0)])[0]
    shell.fan(back, rows[0])  # normal -y
    shell.fan(front, rows[-1][::-1])  # normal +y

    lifters = _Builder()
    facet = radius * math.cos(math.pi / SECTIONS)  # the flat facet's distance from the axis
    for angle in (0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi):
        radial = np.array([math.cos(angle), 0.0, math.sin(angle)])
        tangent = np.array([-math.sin(angle), 0.0, math.cos(angle)])
        axial = np.array([0.0, 1.0, 0.0])
        corners = []
        for r in (facet - lifter_height, facet):
            for w in (-lifter_width / 2, lifter_width / 2):
                for y in (-half, half):
                    corners.append(r * radial + w * tangent + y * axial)
        c = lifters.add(corners)  # index = 4 * (outer) + 2 * (w > 0) + (y > 0)
        lifters.quad(c[0], c[2], c[3], c[1])  # inner face, normal -radial
        lifters.quad(c[4], c[5], c[7], c[6])  # outer face, normal +radial
        lifters.quad(c[0], c[1], c[5], c[4])  # side w < 0, normal -tangent
        lifters.quad(c[2], c[6], c[7], c[3])  # side w > 0, normal +tangent
        lifters.quad(c[0], c[4], c[6], c[2])  # end y < 0, normal -y
        lifters.quad(c[1], c[3], c[7], c[5])  # end y > 0, normal +y
    return {"drum_shell": shell.arrays(), "drum_lifters": lifters.arrays()}


def example_meshes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every example mesh by file stem: ``(vertices [V, 3] float64 (m), faces [F, 3] int64)``."""
    return cone_hopper() | pyramid_hopper() | silo() | lifter_drum()


def main(argv: Sequence[str] | None = None) -> list[Path]:
    """Write the example meshes as binary STL files; returns their paths."""
    parser = argparse.ArgumentParser(
        prog="python -m granular_pyg.scenes.example_meshes",
        description="Write the example equipment meshes (binary STL, metres).",
    )
    parser.add_argument("--out", type=Path, default=MESH_DIR, help=f"folder (default {MESH_DIR})")
    args = parser.parse_args(argv)
    paths = []
    for name, (vertices, faces) in example_meshes().items():
        # Check the triangles as LIGGGHTS will read them (float32 in the file).
        check_wall_for_liggghts(Wall(name, vertices.astype(np.float32), faces))
        path = args.out / f"{name}.stl"
        write_binary_stl(path, vertices, faces)
        paths.append(path)
        print(f"{path}: {len(faces)} triangles, {path.stat().st_size} bytes")
    return paths


if __name__ == "__main__":
    main()
