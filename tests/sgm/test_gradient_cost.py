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


def test_computed_absolute_difference_is_the_table_lookup_bit_for_bit():
    # the gradient cost's kernels compute min(|i - k|, truncation); the generic table path
    # (one load per cell) gives the values that defined it
    rng = np.random.default_rng(5)
    for _ in range(30):
        height, width = rng.integers(1, 40, 2)
        levels = int(rng.choice([2, 16, 256]))
        truncation = int(rng.integers(0, levels + 3))
        left, right = (rng.integers(0, levels, (height, width)).astype(np.uint8)
                       for _ in range(2))
        left_valid = rng.random((height, width)) > 0.2
        right_valid = rng.random((height, width)) > 0.2
        computed = costs.absolute_difference_pixel_cost("ad", left, right, levels=levels,
                                                        truncation=truncation)
        looked_up = costs.table_pixel_cost(
            "ad", left, right, costs.absolute_difference_table(levels, truncation))
        assert computed.max_cost == looked_up.max_cost
        assert computed.kernel_source(left_valid, right_valid, 0)[0] == \
            costs.KIND_ABSOLUTE_DIFFERENCE
        window = int(rng.choice([1, 3, 5]))
        n_disp = int(rng.integers(1, 2 * width + 2))  # also more disparities than columns
        min_disparity = int(rng.integers(-width, width + 1))
        volumes = [costs.windowed_cost_volume(
            cost, left_valid, right_valid, min_disparity=min_disparity,
            num_disparities=n_disp, window=window, rows=(0, height))
            for cost in (computed, looked_up)]
        assert np.array_equal(*volumes)


def test_absolute_difference_values():
    left = np.array([[0, 10, 200]], dtype=np.uint8)
    right = np.array([[5, 0, 0]], dtype=np.uint8)
    valid = np.ones(left.shape, dtype=bool)
    cost = costs.absolute_difference_pixel_cost("ad", left, right, levels=256, truncation=24)
    assert cost.max_cost == 24
    volume = costs.windowed_cost_volume(cost, valid, valid, min_disparity=0,
                                        num_disparities=2, window=1, rows=(0, 1))
    unmatched = costs.unmatched_cost(cost)  # x - d outside the right image
    # x = 0: d 0 → |0 − 5|; x = 1: |10 − 0|, |10 − 5|; x = 2: min(200, 24), min(195, 24)
    assert volume[0].tolist() == [[5, unmatched], [10, 5], [24, 24]]
