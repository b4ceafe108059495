"""argmin_per_group: each group's smallest value, ties to the first row."""

from __future__ import annotations

import torch

from granular_pyg.geometry import argmin_per_group


def test_hand_case_with_a_tie_and_an_absent_group():
    values = torch.tensor([0.5, 0.2, 0.9, 0.2, 0.1, 0.3])
    groups = torch.tensor([3, 3, 0, 3, 5, 0])
    group, row = argmin_per_group(values, groups)
    assert group.tolist() == [0, 3, 5]
    assert row.tolist() == [5, 1, 4]  # group 3: rows 1 and 3 tie at 0.2, the first wins


def test_random_pairs_against_a_loop():
    g = torch.Generator().manual_seed(0)
    groups = torch.randint(0, 50, (2000,), generator=g)
    values = torch.randint(0, 20, (2000,), generator=g).double() / 7  # many ties
    group, row = argmin_per_group(values, groups)
    expected = {}
    for k, (gr, v) in enumerate(zip(groups.tolist(), values.tolist(), strict=True)):
        if gr not in expected or v < values[expected[gr]]:
            expected[gr] = k
    assert group.tolist() == sorted(expected)
    assert row.tolist() == [expected[gr] for gr in sorted(expected)]
