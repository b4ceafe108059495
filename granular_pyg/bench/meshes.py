"""Benchmark scenes: a hopper-shaped funnel mesh at any triangle count, packed particles in it.

Stand-alone so that the geometry benchmark needs nothing but the geometry core; the LIGGGHTS
scenes (``granular_pyg.scenes``) describe the real hopper.
"""

from __future__ import annotations

import math

import torch

#: Funnel dimensions (m): top width in x, depth in y, outlet width, wall angle, total height.
WIDTH, DEPTH, OUTLET, ALPHA_DEG, HEIGHT = 0.10, 0.05, 0.02, 60.0, 0.14


def _patches() -> list[tuple[tuple[float, float, float], ...]]:
    """Planar quads (corners in order) of the funnel: inclines, verticals, front/back, lid."""
    w, d, o = WIDTH / 2, DEPTH / 2, OUTLET / 2
    z1 = (w - o) * math.tan(math.radians(ALPHA_DEG))
    quads = []
    for sx in (-1.0, 1.0):
        quads.append(((sx * o, -d, 0.0), (sx * o, d, 0.0), (sx * w, d, z1), (sx * w, -d, z1)))
        quads.append(((sx * w, -d, z1), (sx * w, d, z1), (sx * w, d, HEIGHT), (sx * w, -d, HEIGHT)))
    for sy in (-1.0, 1.0):
        quads.append(((-o, sy * d, 0.0), (o, sy * d, 0.0), (w, sy * d, z1), (-w, sy * d, z1)))
        quads.append(((-w, sy * d, z1), (w, sy * d, z1), (w, sy * d, HEIGHT), (-w, sy * d, HEIGHT)))
    quads.append(((-o, -d, 0.0), (o, -d, 0.0), (o, d, 0.0), (-o, d, 0.0)))  # lid
    return quads


def _grid_shape(quads: int) -> tuple[int, int]:
    """The most square ``n_u x n_v`` factorisation of ``quads``."""
    n_u = max(k for k in range(1, math.isqrt(quads) + 1) if quads % k == 0)
    return n_u, quads // n_u


def funnel_mesh(num_triangles: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A hopper funnel of 9 planar walls with exactly ``num_triangles`` triangles (even, >= 18).

    Each wall is a bilinear patch split into a grid of quads, two triangles each.

    Returns:
        ``vertices [V, 3]`` float64 (m) and ``faces [num_triangles, 3]`` int64.
    """
    if num_triangles < 18 or num_triangles % 2:
        raise ValueError(f"num_triangles: expected an even number >= 18, got {num_triangles}")
    quads = _patches()
    per_patch, extra = divmod(num_triangles // 2, len(quads))
    vertices, faces, offset = [], [], 0
    for i, corners in enumerate(quads):
        n_u, n_v = _grid_shape(per_patch + (i < extra))
        c = torch.tensor(corners, dtype=torch.float64)
        u = torch.linspace(0, 1, n_u + 1, dtype=torch.float64)[:, None, None]
        v = torch.linspace(0, 1, n_v + 1, dtype=torch.float64)[None, :, None]
        grid = (1 - v) * ((1 - u) * c[0] + u * c[1]) + v * ((1 - u) * c[3] + u * c[2])
        vertices.append(grid.reshape(-1, 3))
        ij = torch.arange((n_u + 1) * (n_v + 1)).reshape(n_u + 1, n_v + 1)
        a, b = ij[:-1, :-1].reshape(-1), ij[1:, :-1].reshape(-1)
        c2, d2 = ij[1:, 1:].reshape(-1), ij[:-1, 1:].reshape(-1)
        faces.append(torch.cat([torch.stack([a, b, c2], 1), torch.stack([a, c2, d2], 1)]) + offset)
        offset += grid.shape[0] * grid.shape[1]
    return torch.cat(vertices), torch.cat(faces)


def packed_particles(num: int, radius: float, seed: int = 0) -> torch.Tensor:
    """``num`` particle centres on a jittered cubic lattice (spacing ``2 radius``) filling the
    funnel from the lid up, each at least ``radius`` from every wall.

    Returns:
        ``[num, 3]`` float64 positions (m).
    """
    spacing = 2.0 * radius
    xs = torch.arange(-WIDTH / 2, WIDTH / 2, spacing, dtype=torch.float64)
    ys = torch.arange(-DEPTH / 2, DEPTH / 2, spacing, dtype=torch.float64)
    zs = torch.arange(0.0, HEIGHT, spacing, dtype=torch.float64)
    lattice = torch.cartesian_prod(xs, ys, zs)
    x, y, z = lattice.unbind(1)
    tan_a, sin_a = math.tan(math.radians(ALPHA_DEG)), math.sin(math.radians(ALPHA_DEG))
    half_width = torch.clamp(OUTLET / 2 + z / tan_a, max=WIDTH / 2)
    margin = torch.where(z < (WIDTH - OUTLET) / 2 * tan_a, radius / sin_a, radius)
    inside = (x.abs() <= half_width - margin) & (y.abs() <= DEPTH / 2 - radius) & (z >= radius)
    inside &= z <= HEIGHT - radius
    lattice = lattice[inside]
    if lattice.shape[0] < num:
        raise ValueError(f"the funnel holds {lattice.shape[0]} particles of {radius} m, not {num}")
    lattice = lattice[torch.argsort(lattice[:, 2], stable=True)[:num]]
    g = torch.Generator().manual_seed(seed)
    return (
        lattice + (torch.rand(lattice.shape, generator=g, dtype=torch.float64) - 0.5) * 0.1 * radius
    )
