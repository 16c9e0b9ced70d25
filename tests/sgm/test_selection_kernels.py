"""The explicit-vector selection kernels of one S row (issue 28) against plain loops:
the right image's disparity from the diagonal of S, on rows whose disparity count is
below one vector, whole vectors, and vectors and a remainder, with ties and ranges that
reach past either image edge."""

import numpy as np
import pytest

from demtool.sgm.disparity import _right_disparities


def _right_by_search(srow, min_disparity):
    """argmin_k S(x_r + d_k, k) for every right pixel x_r, smallest k among ties."""
    width, n_disp = srow.shape
    best = np.full(width, -1, dtype=np.int16)
    for xr in range(width):
        low = None
        for k in range(n_disp):
            x = xr + min_disparity + k
            if 0 <= x < width and (low is None or srow[x, k] < low):
                low, best[xr] = srow[x, k], k
    return best


@pytest.mark.parametrize("n_disp", [5, 16, 21])
@pytest.mark.parametrize("min_disparity", [-30, -7, 0, 4, 30])
def test_right_disparities_equal_a_search_along_the_diagonal(n_disp, min_disparity):
    rng = np.random.default_rng(n_disp + abs(min_disparity))
    srow = rng.integers(0, 6, size=(29, n_disp)).astype(np.uint16)  # many ties
    srow[3, :] = 65535  # the largest cost still wins where it is the only one
    right_best = np.zeros(29, dtype=np.int16)
    _right_disparities(srow, min_disparity, right_best, np.zeros(29, dtype=np.uint32))
    assert np.array_equal(right_best, _right_by_search(srow, min_disparity))
