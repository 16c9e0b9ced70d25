"""The horizontal Sobel gradient of the gradient cost (demtool.sgm.cost.horizontal_sobel)."""

import numpy as np
from scipy import ndimage

from demtool.sgm import cost as costs


def scipy_gradient(image, valid):
    """What the gradient cost computed before: scipy's Sobel in float64, then float32."""
    filled = costs.fill_invalid(image, valid).astype(np.float64)
    return np.where(valid, ndimage.sobel(filled, axis=1), np.nan).astype(np.float32)


def test_equal_to_scipys_sobel_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(40):
        height, width = rng.integers(1, 60, 2)  # single rows and columns: the reflect edges
        scale = 10.0 ** rng.uniform(-5, 8)  # float64 rounding at every magnitude
        image = (rng.normal(size=(height, width)) * scale + rng.normal() * 10 * scale)
        image = image.astype(np.float32)
        valid = rng.random((height, width)) > 0.2
        valid[0, 0] = True
        image[~valid] = np.nan
        found = costs.horizontal_sobel(costs.fill_invalid(image, valid), valid)
        expected = scipy_gradient(image, valid)
        assert found.dtype == np.float32
        assert np.array_equal(found, expected, equal_nan=True)
        assert np.array_equal(np.isnan(found), ~valid)


def test_a_ramp_and_a_step():
    # x ramp of slope 3: d/dx by central differences is 6 per 2 px, smoothed 1 + 2 + 1
    ramp = np.tile(3.0 * np.arange(6, dtype=np.float32), (4, 1))
    valid = np.ones(ramp.shape, dtype=bool)
    gradient = costs.horizontal_sobel(ramp, valid)
    assert np.all(gradient[:, 1:-1] == 4 * 6.0)
    assert np.all(gradient[:, [0, -1]] == 4 * 3.0)  # reflected edges: one-sided difference
    step = np.zeros((3, 4), dtype=np.float32)
    step[:, 2:] = 1.0
    assert costs.horizontal_sobel(step, np.ones(step.shape, bool)).tolist() == [
        [0.0, 4.0, 4.0, 0.0]] * 3
