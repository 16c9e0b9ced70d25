"""Work moved onto threads gives the one-thread result to the bit."""

from __future__ import annotations

import numpy as np

from demtool.sgm.disparity import matchable
from demtool.sgm.matcher import sgm
from tests.sgm.test_margins import textured_pair


def test_census_on_two_threads_equals_one_thread():
    left, right = textured_pair(96, 6.0, seed=5)
    left[10:14, 30:40] = np.nan
    options = dict(min_disparity=0, num_disparities=24, cost="census")
    one = sgm(left, right, workers=1, **options)
    two = sgm(left, right, workers=2, **options)
    np.testing.assert_array_equal(one.disparity, two.disparity)
    np.testing.assert_array_equal(one.confidence, two.confidence)
    np.testing.assert_array_equal(one.classes, two.classes)


def test_matchable_in_row_halves():
    rng = np.random.default_rng(2)
    disparity = rng.uniform(-5, 40, size=(300, 64)).astype(np.float32)
    disparity[rng.random(disparity.shape) < 0.1] = np.nan
    right_valid = rng.random(disparity.shape) > 0.2
    got = matchable(disparity, right_valid)
    xs = np.arange(64)[None, :]
    with np.errstate(invalid="ignore"):
        match = np.rint(xs - disparity)
    inside = np.isfinite(match) & (match >= 0) & (match < 64)
    rows = np.broadcast_to(np.arange(300)[:, None], disparity.shape)
    ok = inside.copy()
    ok[inside] = right_valid[rows[inside], match[inside].astype(int)]
    want = np.where(ok, disparity, np.float32(np.nan))
    np.testing.assert_array_equal(got, want)
