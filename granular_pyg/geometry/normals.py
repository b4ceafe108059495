r"""Triangle normals and the paper's orientation-independent ("canonical") normal features.

A wall triangle has two valid normals, :math:`n` and :math:`-n`; which one a mesh stores depends
on its vertex order. The paper makes the model independent of that choice by feeding both,
ordered by the partial-order key

.. math::

    f_o(n) = \sum_{i=1}^{3} 3^{i-1} \, (\operatorname{sgn}(n_i) + 1) \in \{0, \dots, 26\}.

Since :math:`\operatorname{sgn}(-x) = -\operatorname{sgn}(x)`, :math:`f_o(-n) = 26 - f_o(n)`:
the two keys differ for every non-zero normal, so the order is strict, and flipping a normal
swaps the keys, so the ordered pair does not change.

**Order used here: the orientation with the smaller key goes first**, as in the paper's R3/R4
(:math:`n, -n` if :math:`f_o(n) \le f_o(-n)`). (BGNN's code puts the larger key first; the two
conventions are equivalent for learning.)
"""

from __future__ import annotations

import torch

from granular_pyg.errors import check_tensor

__all__ = ["canonical_normals", "orientation_key", "triangle_normals"]

#: Components with ``|n_i| <= ZERO_TOL * |n|`` count as zero in :func:`orientation_key`.
ZERO_TOL = 1e-6


def triangle_normals(triangles: torch.Tensor) -> torch.Tensor:
    """Unit normals from the vertex order (right-hand rule: ``(v1 - v0) x (v2 - v0)``).

    Args:
        triangles: ``[F, 3, 3]`` vertices (m).

    Returns:
        ``[F, 3]`` unit normals; exactly zero for a zero-area triangle (never NaN).
    """
    check_tensor("triangles", triangles, (None, 3, 3))
    v0, v1, v2 = triangles.unbind(dim=-2)
    cross = torch.linalg.cross(v1 - v0, v2 - v0)
    norm = torch.linalg.vector_norm(cross, dim=-1, keepdim=True)
    tiny = torch.finfo(triangles.dtype).tiny
    return torch.where(norm > tiny, cross / norm.clamp_min(tiny), torch.zeros_like(cross))


def orientation_key(normals: torch.Tensor, zero_tol: float = ZERO_TOL) -> torch.Tensor:
    r"""The paper's partial-order key :math:`f_o(n) = \sum_i 3^{i-1} (\operatorname{sgn}(n_i) + 1)`.

    A component whose magnitude is at most ``zero_tol * |n|`` counts as zero, so that round-off
    in a mesh's vertices (a wall normal of ``(1, 0, 1e-12)``) does not change the key. The
    threshold is symmetric in ``n -> -n``, so ``f_o(-n) = 26 - f_o(n)`` still holds exactly.

    Args:
        normals: ``[..., 3]``.
        zero_tol: relative threshold below which a component counts as zero; 0 for the bare
            formula.

    Returns:
        ``[...]`` int64 keys in ``0..26``.
    """
    scale = torch.linalg.vector_norm(normals, dim=-1, keepdim=True) * zero_tol
    sign = torch.where(normals.abs() <= scale, torch.zeros_like(normals), torch.sign(normals))
    weights = torch.tensor([1, 3, 9], dtype=torch.int64, device=normals.device)
    return ((sign.to(torch.int64) + 1) * weights).sum(dim=-1)


def canonical_normals(normals: torch.Tensor, zero_tol: float = ZERO_TOL) -> torch.Tensor:
    """Both orientations of each normal, smaller :func:`orientation_key` first.

    The result is bit-identical for ``normals`` and ``-normals`` (negative zeros are
    normalised to ``+0.0``). Its first three columns are the paper's single canonical
    normal (R3); all six are the ordered pair (R4, the simulator's V3 feature).

    Args:
        normals: ``[F, 3]`` normals (any length; zero rows stay zero).
        zero_tol: see :func:`orientation_key`.

    Returns:
        ``[F, 6]``: ``[first, second]`` with ``f_o(first) <= f_o(second)``.
    """
    check_tensor("normals", normals, (None, 3))
    n_first = orientation_key(normals, zero_tol) <= orientation_key(-normals, zero_tol)
    first = torch.where(n_first.unsqueeze(-1), normals, -normals)
    return torch.cat([first, -first], dim=-1) + 0.0  # "+ 0.0" turns -0.0 into +0.0
