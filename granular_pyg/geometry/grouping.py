"""Per-group selection over flat pair lists (particle-triangle pairs grouped by particle)."""

from __future__ import annotations

import torch

__all__ = ["argmin_per_group"]


def argmin_per_group(
    values: torch.Tensor, groups: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The row of the smallest value in each group; ties go to the first row.

    Args:
        values: ``[K]`` finite values (any unit), e.g. distances (m) or fractions along a move.
        groups: ``[K]`` int64 group of each row, e.g. the particle index of a pair.

    Returns:
        ``(group [G], row [G])``: the groups present, ascending, and the index into ``values``
        of each group's smallest value.
    """
    unique, inverse = torch.unique(groups, return_inverse=True)
    best = torch.full((unique.numel(),), torch.inf, dtype=values.dtype)
    best = best.scatter_reduce(0, inverse, values, "amin")
    ties = (values == best[inverse]).nonzero().squeeze(1)
    first = torch.full((unique.numel(),), groups.numel(), dtype=torch.long)
    first = first.scatter_reduce(0, inverse[ties], ties, "amin")
    return unique, first
