"""The fuse core: border weights, weighted median / mean after outlier rejection, count,
spread and combined error, consensus NMAD, co-registration shift."""

import numpy as np
import pytest

from demtool.errors import ProcessingError
from demtool.fuse.core import (
    MEDIAN_EFFICIENCY,
    border_weights,
    combine,
    consensus_nmad,
    estimate_shift,
    stack_nmad,
)


def test_border_weights_grow_with_distance_to_the_data_edge():
    valid = np.zeros((40, 40), dtype=bool)
    valid[5:35, 5:35] = True
    w = border_weights(valid, blend_px=8, exponent=2)
    assert w[~valid].max() == 0
    assert w[5, 20] == pytest.approx((1 / 8) ** 2)  # next to the edge: distance 1 cell
    assert w[9, 20] == pytest.approx((5 / 8) ** 2)
    assert w[20, 20] == 1.0  # farther than the blending length
    # the array's own edge is not a border; blend 0 = uniform
    assert border_weights(np.ones((5, 5), bool), blend_px=8).min() == 1.0
    np.testing.assert_array_equal(border_weights(valid, blend_px=0), valid.astype(float))


def test_mean_rejects_an_outlier_and_reports_count_spread_error():
    values = np.array([10.0, 10.2, 9.8, 60.0])[:, None, None] * np.ones((4, 2, 3))
    weights = np.ones_like(values)
    result = combine(values, weights, method="mean", outlier_k=3)
    np.testing.assert_allclose(result.dem, 10.0, atol=1e-6)
    np.testing.assert_array_equal(result.count, 3)
    spread = 1.4826 * 0.2  # NMAD of 9.8, 10, 10.2
    np.testing.assert_allclose(result.spread, spread, rtol=1e-5)
    np.testing.assert_allclose(result.error, spread / np.sqrt(3), rtol=1e-5)


def test_weighted_median_follows_the_error_rasters():
    values = np.array([1.0, 2.0, 3.0])[:, None, None] * np.ones((3, 1, 1))
    weights = np.ones_like(values)
    errors = np.array([0.1, 1.0, 1.0])[:, None, None] * np.ones((3, 1, 1))
    result = combine(values, weights, errors, method="median", outlier_k=10)
    assert result.dem[0, 0] == 1.0  # weight 100 against 1 + 1
    # equal weights: the ordinary median; two values: their mean
    equal = combine(values, weights, np.ones_like(values), method="median", outlier_k=10)
    assert equal.dem[0, 0] == 2.0
    two = combine(values[:2], weights[:2], np.ones((2, 1, 1)), method="median")
    assert two.dem[0, 0] == 1.5
    # combined error: the weighted mean's standard error times sqrt(pi/2)
    w = 1 / np.array([0.01, 1.0, 1.0])
    expected = np.sqrt((w**2 * np.array([0.01, 1, 1])).sum()) / w.sum() * MEDIAN_EFFICIENCY
    assert result.error[0, 0] == pytest.approx(expected, rel=1e-5)


def test_weighted_mean_uses_border_and_error_weights():
    values = np.array([0.0, 4.0])[:, None, None] * np.ones((2, 1, 1))
    result = combine(values, np.array([1.0, 3.0])[:, None, None], method="mean")
    assert result.dem[0, 0] == pytest.approx(3.0)
    errors = np.array([1.0, 2.0])[:, None, None] * np.ones((2, 1, 1))
    result = combine(values, np.ones((2, 1, 1)), errors, method="mean")
    assert result.dem[0, 0] == pytest.approx(4.0 * 0.25 / 1.25)
    assert result.error[0, 0] == pytest.approx(np.sqrt(1 + 0.25 ** 2 * 4) / 1.25)


def test_huber_is_the_weighted_mean_of_agreeing_values_and_bounds_a_blunder():
    ones = np.ones((4, 2, 3))
    values = np.array([10.0, 10.2, 9.8, 10.4])[:, None, None] * ones
    weights = np.array([1.0, 2.0, 1.0, 1.0])[:, None, None] * ones
    # every residual within c × scale: Huber's weights are all 1, the weighted mean
    result = combine(values, weights, method="huber", scale_floor=1.0)
    np.testing.assert_allclose(result.dem, (10 + 20.4 + 9.8 + 10.4) / 5, rtol=1e-6)
    np.testing.assert_array_equal(result.count, 4)
    # a 50 m blunder is kept but its influence bounded: weight c s / 50 against 1
    values = np.array([10.0, 10.2, 9.8, 60.0])[:, None, None] * ones
    result = combine(values, np.ones_like(values), method="huber", scale_floor=0.1)
    scale = 1.4826 * 0.2  # the cell's NMAD (residuals 0.1, 0.1, 0.3, 49.9 to 10.1)
    bound = 1.345 * scale / 3  # at most c s of weighted residual over the other three
    assert np.all(np.abs(result.dem - 10.0) <= bound)
    assert np.all(np.abs(result.dem - 10.0) > 0.0)
    np.testing.assert_array_equal(result.count, 4)
    assert combine(values, np.ones_like(values), method="mean").dem[0, 0] == \
        pytest.approx(10.0, abs=1e-6)  # the rejection of mean cuts it instead


def test_stack_nmad_is_the_spread_against_the_cell_medians():
    offsets = np.array([0.0, 0.1, 0.3])[:, None, None]
    stack = offsets + np.zeros((3, 4, 5))
    stack[2, 0, 0] = np.nan  # a cell with two values: residuals ±0.05 to their median
    # residuals to the median: 0.1, 0, 0.2 in 19 cells; 0.05, 0.05 in one
    assert stack_nmad(stack) == pytest.approx(1.4826 * 0.1)
    assert stack_nmad(np.full((2, 3, 3), np.nan)) == 0.0


def test_cells_without_values_stay_empty_and_single_values_have_no_spread():
    values = np.full((2, 1, 3), np.nan)
    values[0, 0, 1] = 5.0
    weights = np.where(np.isfinite(values), 1.0, 0.0)
    for method, errors in (("mean", None), ("median", np.ones_like(values)),
                           ("huber", None)):
        result = combine(values, weights, errors, method=method)
        assert np.isnan(result.dem[0, 0]) and result.dem[0, 1] == 5.0
        np.testing.assert_array_equal(result.count[0], [0, 1, 0])
        assert np.isnan(result.spread).all()


def test_median_without_errors_and_bad_arguments_are_refused():
    values = np.zeros((2, 1, 1))
    with pytest.raises(ValueError, match="error raster"):
        combine(values, np.ones_like(values), method="median")
    with pytest.raises(ValueError, match="unknown method"):
        combine(values, np.ones_like(values), method="mode")
    with pytest.raises(ValueError, match="outlier_k"):
        combine(values, np.ones_like(values), outlier_k=0.5)


def test_consensus_nmad_singles_out_the_noisy_dem():
    rng = np.random.default_rng(1)
    base = rng.standard_normal((60, 60)) * 5
    stack = np.stack([base + 0.05 * rng.standard_normal(base.shape) for _ in range(3)]
                     + [base + 2.0 * rng.standard_normal(base.shape)])
    nmad = consensus_nmad(stack)
    assert nmad[3] == pytest.approx(2.0, rel=0.1)
    assert nmad[:3].max() < 0.15
    from demtool.fuse.tiled import on_threads  # the run maps the DEMs on threads

    stack[1, :20] = np.nan
    assert np.array_equal(consensus_nmad(stack, on_threads), consensus_nmad(stack))


def test_estimate_shift_recovers_a_known_shift_and_needs_overlap():
    rows, cols = np.mgrid[0:120, 0:120].astype(float)

    def relief(r, c):
        return 8 * np.sin(c / 9.0) + 6 * np.cos(r / 7.0 + c / 23.0)

    reference = relief(rows, cols)
    dem = relief(rows - 1.5, cols + 0.75) + 2.0  # content moved by (dx, dy) = (-0.75, 1.5)
    alignment = estimate_shift(dem, reference, method="nuth-kaab")
    shift = alignment["shift"]
    assert shift["dx_px"] == pytest.approx(0.75, abs=0.05)
    assert shift["dy_px"] == pytest.approx(-1.5, abs=0.05)
    assert shift["dz"] == pytest.approx(-2.0, abs=0.05)
    empty = np.full_like(dem, np.nan)
    with pytest.raises(ProcessingError, match="no common overlap"):
        estimate_shift(empty, reference, label="a.tif")


def _numpy_nanmedian(values, valid):
    """numpy's nanmedian of the valid values along axis 0; NaN where none is valid."""
    filled = np.where(valid, values, np.nan)
    some = valid.any(axis=0)
    expected = np.full(some.shape, np.nan)
    expected[some] = np.nanmedian(filled[:, some], axis=0)
    return expected


def test_nan_median_is_numpys_nanmedian_to_the_bit():
    from demtool.fuse.core import _nan_median

    rng = np.random.default_rng(3)
    for count in (1, 2, 3, 4, 7):
        values = rng.normal(size=(count, 40, 30))
        valid = rng.random(values.shape) > 0.3
        np.testing.assert_array_equal(_nan_median(values, valid), _numpy_nanmedian(values, valid))


def test_nan_median_with_ties_and_signed_zeros_is_numpys():
    """The compiled median against numpy's, on values with ties (rounded) and zeros of
    both signs: equal numbers (numpy's sort does not order −0 and +0 either)."""
    from demtool.fuse.core import _nan_median

    rng = np.random.default_rng(11)
    for count in (1, 2, 3, 5, 8):
        values = np.round(rng.normal(size=(count, 25, 20)), 1)
        valid = rng.random(values.shape) > 0.25
        np.testing.assert_array_equal(_nan_median(values, valid), _numpy_nanmedian(values, valid))
    flat = _nan_median(np.array([[1.0, 4.0], [3.0, 2.0], [2.0, 9.0]]), np.ones((3, 2), bool))
    np.testing.assert_array_equal(flat, [2.0, 4.0])  # (N, M) stacks too


def test_compiled_distances_are_scipys_edt_to_the_bit():
    """The border weights' distance transform against scipy's exact EDT: random masks,
    a column and a row without background, holes in a large valid area."""
    from scipy.ndimage import binary_dilation, distance_transform_edt

    from demtool.fuse.core import _distances

    rng = np.random.default_rng(5)
    masks = [rng.random((int(h), int(w))) < rng.uniform(0.3, 0.99)
             for h, w in rng.integers(1, 50, size=(60, 2))]
    lined = np.ones((30, 40), bool)
    lined[7, 3] = False  # one background cell: every other column has none
    holes = ~binary_dilation(rng.random((300, 260)) < 5e-4, iterations=6)
    holes[:, :20] = False
    for mask in [*masks, lined, holes]:
        if mask.all():
            mask[0, 0] = False
        expected = distance_transform_edt(mask)
        got = _distances(mask)
        assert got.dtype == np.float64
        assert np.array_equal(got.view(np.uint64), expected.view(np.uint64))


def _huber_numpy(values, weights, start, scale, iterations=10, c=1.345):
    """The whole-array numpy form of Huber's IRLS that the compiled kernel replaced."""
    present = weights > 0
    filled = np.where(present, values, 0.0)
    mu = np.where(np.isfinite(start), start, 0.0)
    w = weights
    for _ in range(iterations):
        u = np.abs(filled - mu) / scale
        w = np.where(present, weights * np.minimum(1.0, c / np.maximum(u, 1e-12)), 0.0)
        total = w.sum(axis=0)
        mu = np.where(total > 0, (w * filled).sum(axis=0) / np.where(total > 0, total, 1.0),
                      mu)
    return w


def test_compiled_huber_gives_the_numpy_weights_to_the_bit():
    from demtool.fuse.core import HUBER_C, HUBER_ITERATIONS, _huber, _nan_median

    rng = np.random.default_rng(8)
    for count in (1, 2, 3, 7):
        values = rng.normal(size=(count, 30, 20)) + 5 * (rng.random((count, 30, 20)) < 0.1)
        weights = np.where(rng.random(values.shape) < 0.2, 0.0, rng.random(values.shape))
        values[weights == 0] = np.nan  # absent values are NaN in combine
        start = _nan_median(values, weights > 0)  # NaN where no value: mu starts at 0
        scale = rng.uniform(0.01, 1.0, start.shape)
        np.testing.assert_array_equal(
            _huber(values, weights, start, scale),
            _huber_numpy(values, weights, start, scale, HUBER_ITERATIONS, HUBER_C))
