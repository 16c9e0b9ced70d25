"""The match kernels over row parts on threads give the one-thread result to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.match import lsm_match
from demtool.match.between import refine_translation
from demtool.match.ncc import ncc_search
from tests.helpers.match import textured_pair
from tests.helpers.row_parts import whole_and_split


def _templates():
    left, right, truth = textured_pair(96, 128, seed=5, noise=0.01)
    left[40:44, 60:70] = np.nan  # nodata: some templates fail, as in a real pair
    rows, cols = np.meshgrid(np.arange(8, 88, 3), np.arange(8, 120, 4), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    return left, right, truth, rows, cols


def _assert_identical(whole, split, seen):
    assert any(len(parts) > 1 for parts in seen)  # the kernel did run in parts
    for a, b in zip(whole, split, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("method", ["forward", "inverse"])
def test_lsm_in_parts_is_the_one_thread_result(monkeypatch, method):
    left, right, truth, rows, cols = _templates()
    start = cols - np.round(np.nan_to_num(truth[rows, cols])) + 0.3

    def compute():
        return lsm_match(left, right, rows, cols, start, rows.astype(float), template=11,
                         weighting=2.0, method=method)

    whole, split, seen = whole_and_split(monkeypatch, compute)
    assert (whole.status == 0).mean() > 0.8
    _assert_identical(whole, split, seen)


def test_ncc_in_parts_is_the_one_thread_result(monkeypatch):
    left, right, truth, rows, cols = _templates()
    low = np.full(rows.shape, 0)
    high = np.full(rows.shape, 12)

    def compute():
        return ncc_search(left, right, rows, cols, low, high, template=11)

    whole, split, seen = whole_and_split(monkeypatch, compute)
    assert np.isfinite(whole.disparity).mean() > 0.8
    _assert_identical(whole, split, seen)


def test_translation_refinement_in_parts_is_the_one_thread_result(monkeypatch):
    left, right, truth, rows, cols = _templates()
    start = cols - truth[rows, cols] + 0.2
    affine = np.tile([1.0, 0.0, 0.0, 1.0], (rows.size, 1))

    def compute():
        return refine_translation(left, right, rows, cols, start, rows.astype(float), affine,
                                  template=11, weighting=2.0, iterations=2)

    whole, split, seen = whole_and_split(monkeypatch, compute)
    assert whole.ok.mean() > 0.8
    assert len(seen) == 2  # the gradients' rows, then the templates
    _assert_identical(whole, split, seen)
