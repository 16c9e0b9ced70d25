"""The explicit-vector selection kernels of one S row (issue 28) against plain numpy:
the winner-takes-all with its second-best cost, and the right image's disparity from
the diagonal of S, on rows whose disparity count is below one vector, whole vectors,
and vectors and a remainder, with ties and ranges that reach past either image edge."""

import numpy as np
import pytest
from numba import njit

from demtool.sgm.disparity import _best_two, _right_disparities
from demtool.sgm.simd import best_two


@njit(cache=False)
def _best_two_of_row(srow, vectors):
    out = np.empty((srow.shape[0], 3), dtype=np.int64)
    for x in range(srow.shape[0]):
        out[x] = best_two(srow, x) if vectors else _best_two(srow, x)
    return out


@pytest.mark.parametrize("n_disp", [3, 5, 16, 21, 40])
def test_winner_and_second_best_equal_numpy(n_disp):
    rng = np.random.default_rng(n_disp)
    srow = rng.integers(0, 4, size=(200, n_disp)).astype(np.uint16)  # many ties
    srow[:50] = rng.integers(0, 65536, size=(50, n_disp))
    srow[7] = 65535
    best = srow.argmin(axis=1)  # the first index of the least cost
    masked = srow.astype(np.int64)
    for offset in (-1, 0, 1):
        np.put_along_axis(masked, np.clip(best + offset, 0, n_disp - 1)[:, None], 65535, 1)
    expected = np.stack([best, srow.min(axis=1), masked.min(axis=1)], axis=1)
    assert np.array_equal(_best_two_of_row(srow, False), expected)
    if n_disp >= 16:
        assert np.array_equal(_best_two_of_row(srow, True), expected)


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
