"""Window maxima and minima of cost "auto"'s zones (issue 28): scipy.ndimage's filters."""

import numpy as np
import pytest
from scipy import ndimage

from demtool.sgm import disparity
from demtool.sgm.extremes import box_max, box_min, percentiles


@pytest.mark.parametrize("split", [2, 10 ** 9])  # halves in two threads, or one
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_box_extremes_equal_scipys_maximum_and_minimum_filters(dtype, split, monkeypatch):
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", split)
    rng = np.random.default_rng(7)
    for _ in range(60):
        shape = tuple(rng.integers(1, 50, 2))  # also smaller than the window
        radius = int(rng.integers(0, 14))
        values = rng.normal(size=shape).astype(dtype)
        values[rng.random(shape) < 0.1] = np.inf
        values[rng.random(shape) < 0.1] = -np.inf
        size = 2 * radius + 1
        high, low = box_max(values, radius), box_min(values, radius)
        assert high.dtype == dtype and low.dtype == dtype
        assert np.array_equal(high, ndimage.maximum_filter(values, size=size))
        assert np.array_equal(low, ndimage.minimum_filter(values, size=size))
        mask = rng.random(shape) < 0.05
        assert np.array_equal(box_max(mask, radius) > 0, ndimage.maximum_filter(mask, size=size))


def test_box_max_of_one_pixel_is_its_clipped_square():
    values = np.zeros((7, 9), dtype=np.float32)
    values[1, 7] = 5.0
    expected = np.zeros_like(values)
    expected[0:4, 5:9] = 5.0  # rows 1 ± 2 and columns 7 ± 2, clipped
    assert np.array_equal(box_max(values, 2), expected)


def _bits(values: np.ndarray) -> bytes:
    return np.ascontiguousarray(values).view(np.uint8).tobytes()


def test_percentiles_are_numpys_bit_for_bit():
    rng = np.random.default_rng(11)
    samples = [rng.normal(size=200_003).astype(np.float32),
               rng.integers(0, 40, size=150_000).astype(np.float32),  # many ties
               np.exp(5.0 * rng.normal(size=100_001)),  # float64, heavy tail
               np.concatenate([np.full(90_000, 3.0), rng.normal(size=9_000)]),  # a plateau
               rng.normal(size=5000).astype(np.float32),  # the sample is all of it
               rng.normal(size=1000).astype(np.float32)]  # small: numpy itself
    for values in samples:
        for q in [(0.5, 99.5), (1.0, 50.0, 99.0), (0.0, 100.0), (37.3,), (99.99, 0.01)]:
            expected = np.percentile(values, q)
            found = percentiles(values, q)
            assert found.dtype == expected.dtype
            assert _bits(found) == _bits(expected), (values.dtype, values.size, q)


def test_percentiles_of_a_sample_with_nan_are_numpys():
    values = np.random.default_rng(2).normal(size=100_000).astype(np.float32)
    values[17] = np.nan
    assert np.isnan(percentiles(values, (0.5, 99.5))).all()
