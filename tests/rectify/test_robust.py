"""The row-residual inlier test both pointing fits share (demtool.rectify.robust): the
same inliers as each fit's own test before they shared it, NaN handled as each needs."""

from __future__ import annotations

import numpy as np

from demtool.rectify.calibrated import _robust_inliers
from demtool.rectify.relative_pose import _inliers


def residual_sample(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    residuals = rng.normal(0.3, 0.5, 400)
    residuals[rng.choice(400, 30, replace=False)] += rng.choice([-1, 1], 30) * 9.0
    return residuals


def test_inliers_are_those_within_four_nmad_or_the_floor_of_the_median():
    for seed in range(5):
        residuals = residual_sample(seed)
        med = np.median(residuals)
        nmad = 1.4826 * np.median(np.abs(residuals - med))
        for floor in (0.5, 2.0, 30.0):
            expected = np.abs(residuals - med) <= max(floor, 4.0 * nmad)
            assert np.array_equal(_robust_inliers(residuals, floor), expected)
            assert np.array_equal(_inliers(residuals, floor), expected)
        assert 360 <= _inliers(residuals, 0.5).sum() <= 370  # the 30 gross errors out
        assert _inliers(residuals, 30.0).all()  # a floor beyond them keeps every match


def test_nan_residuals_are_outliers_of_the_relative_pose_and_void_the_pointing_fit():
    residuals = residual_sample(7)
    residuals[[3, 50]] = np.nan
    finite = np.isfinite(residuals)
    inliers = _inliers(residuals, 1.0)
    assert not inliers[[3, 50]].any()
    assert np.array_equal(inliers[finite], _inliers(residuals[finite], 1.0))
    assert not _robust_inliers(residuals, 1.0).any()  # the median is NaN: no inlier
