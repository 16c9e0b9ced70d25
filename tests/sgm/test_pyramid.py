"""The HMI pyramid's block means (demtool.sgm.pyramid)."""

import numpy as np
import pytest

from demtool.sgm.pyramid import downsample


def reference_block_means(image, valid):
    """The formula downsample replaced: numpy's mean over each 2 × 2 block."""
    height, width = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
    blocks = np.where(valid, image, 0.0)[:height, :width].reshape(height // 2, 2, width // 2, 2)
    block_valid = valid[:height, :width].reshape(height // 2, 2, width // 2, 2).all(axis=(1, 3))
    return blocks.mean(axis=(1, 3)).astype(np.float32), block_valid


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_block_means_equal_numpys_mean_bit_for_bit(dtype):
    rng = np.random.default_rng(7)
    for _ in range(25):
        height, width = rng.integers(2, 300, 2)
        scale = 10.0 ** rng.uniform(-4, 7)  # float rounding at every magnitude
        image = (rng.normal(size=(height, width)) * scale + scale).astype(dtype)
        valid = rng.random((height, width)) > 0.15
        image[~valid & (rng.random((height, width)) > 0.5)] = np.nan  # NaN where invalid
        means, block_valid = downsample(image, valid)
        expected, expected_valid = reference_block_means(image, valid)
        assert means.dtype == np.float32 and means.shape == (height // 2, width // 2)
        assert np.array_equal(means.view(np.uint32), expected.view(np.uint32))
        assert np.array_equal(block_valid, expected_valid)


def test_block_means_of_a_known_image():
    image = np.arange(20, dtype=np.float32).reshape(4, 5)  # the odd last column is dropped
    valid = np.ones_like(image, dtype=bool)
    valid[3, 0] = False
    means, block_valid = downsample(image, valid)
    # blocks (0, 1, 5, 6), (2, 3, 7, 8); (10, 11, 15, 16), (12, 13, 17, 18); 15 invalid = 0
    assert means.tolist() == [[3.0, 5.0], [37 / 4, 15.0]]
    assert block_valid.tolist() == [[True, True], [False, True]]
