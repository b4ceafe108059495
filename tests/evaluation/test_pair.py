"""Helpers of the per-trajectory evaluation."""

from __future__ import annotations

import warnings

import numpy as np

from granular_pyg.evaluation.pair import _column_nanmean


def test_column_means_skip_nan_and_leave_empty_columns_nan_without_a_warning():
    values = np.array([[1.0, np.nan, np.nan], [3.0, 2.0, np.nan]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        means = _column_nanmean(values)
    np.testing.assert_array_equal(means[:2], [2.0, 2.0])
    assert np.isnan(means[2])
