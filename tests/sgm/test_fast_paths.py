"""The numba paths of the SGM pre- and post-processing equal their numpy definitions."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.sgm.disparity import matchable
from demtool.sgm.matcher import noise_sigma


@pytest.mark.parametrize("shape", [(3, 3), (57, 83), (120, 95)])
def test_noise_of_a_uint8_guide_equals_the_float_definition(shape):
    rng = np.random.default_rng(shape[0])
    image = np.clip(rng.normal(128, 6, shape), 0, 255).astype(np.uint8)
    valid = rng.random(shape) > 0.1
    for mask in (valid, np.ones(shape, dtype=bool)):
        assert noise_sigma(image, mask) == noise_sigma(image.astype(np.float64), mask)


def test_noise_of_white_noise_is_its_sigma():
    rng = np.random.default_rng(1)
    image = np.clip(np.rint(rng.normal(128, 4.0, (400, 400))), 0, 255).astype(np.uint8)
    assert noise_sigma(image, np.ones(image.shape, dtype=bool)) == pytest.approx(4.0, rel=0.05)
    assert noise_sigma(image, np.zeros(image.shape, dtype=bool)) == 0.0


def test_matchable_drops_matches_outside_or_on_invalid_right_pixels():
    disparity = np.array([[0.0, 1.4, 2.6, np.nan, 5.0]], dtype=np.float32)
    right_valid = np.array([[True, False, True, True, True]])
    out = matchable(disparity, right_valid)
    # x - d: 0 -> 0 ok; 1 - 1.4 -> -0.4 rounds to 0 ok (-0 valid); 2 - 2.6 -> -1 outside;
    # NaN stays NaN; 4 - 5 -> -1 outside
    np.testing.assert_array_equal(out, np.array([[0.0, 1.4, np.nan, np.nan, np.nan]],
                                                dtype=np.float32))
    assert out.dtype == np.float32 and disparity[0, 2] == np.float32(2.6)
