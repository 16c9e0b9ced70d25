"""Window maxima and minima of cost "auto"'s zones (issue 28): scipy.ndimage's filters."""

import numpy as np
import pytest
from scipy import ndimage

from demtool.sgm.extremes import box_max, box_min


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_box_extremes_equal_scipys_maximum_and_minimum_filters(dtype):
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
