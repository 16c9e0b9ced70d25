"""Nearest neighbours both ways in one pass over each block of the distance matrix
(demtool.imaging.nearest), against the numpy formula it replaced."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.imaging import features
from demtool.imaging.nearest import nearest_both_ways


def numpy_fold(d2, start, indices, distances, best_a_for_b, best_b_distance):
    """The numpy formula the kernel replaced: argpartition along the rows, argmin down
    the columns (which copies the block transposed)."""
    d2 = np.maximum(d2, 0.0)
    n_b = d2.shape[1]
    k = min(2, n_b)
    nearest = np.argpartition(d2, k - 1, axis=1)[:, :k] if n_b > k else \
        np.tile(np.arange(k), (len(d2), 1))
    nearest_d = np.take_along_axis(d2, nearest, axis=1)
    order = np.argsort(nearest_d, axis=1)
    indices[start:start + len(d2), :k] = np.take_along_axis(nearest, order, axis=1)
    distances[start:start + len(d2), :k] = np.take_along_axis(nearest_d, order, axis=1)
    column_best = np.argmin(d2, axis=0)
    column_d = d2[column_best, np.arange(n_b)]
    better = column_d < best_b_distance
    best_b_distance[better] = column_d[better]
    best_a_for_b[better] = column_best[better] + start


def folded(fold, blocks, n_b):
    n_a = sum(len(b) for b in blocks)
    state = (np.full((n_a, 2), -1, np.int64), np.full((n_a, 2), np.inf),
             np.zeros(n_b, np.int64), np.full(n_b, np.inf))
    start = 0
    for block in blocks:
        fold(block, start, *state)
        start += len(block)
    return state


@pytest.mark.parametrize(("n_b", "block_rows"), [(500, 300), (500, 7), (1, 40), (2, 40),
                                                 (3, 1)])
def test_the_same_neighbours_and_distances_as_numpy(n_b, block_rows):
    """Random float32 distances (no ties; some below 0, as rounding leaves them), in one
    block or blocks of 7 rows, and the small sets where ``b`` has one or two rows."""
    rng = np.random.default_rng(n_b + block_rows)
    d2 = rng.uniform(-1.0, 1e5, (300 if block_rows > 1 else 1, n_b)).astype(np.float32)
    blocks = [d2[i:i + block_rows] for i in range(0, len(d2), block_rows)]
    got = folded(nearest_both_ways, blocks, n_b)
    expected = folded(numpy_fold, blocks, n_b)
    for mine, theirs in zip(got, expected, strict=True):
        np.testing.assert_array_equal(mine, theirs)


def test_ties_go_to_the_lower_index():
    """Two identical columns: the lower is the nearest, the higher the second; a row
    repeated in ``a``: the first is each column's nearest."""
    rng = np.random.default_rng(3)
    b = rng.uniform(0, 50, (6, 16)).astype(np.float32)
    b[4] = b[1]
    a = np.stack([b[1] + 0.25, b[1] + 0.25, b[3] + 0.5]).astype(np.float32)
    indices, distances, best_a_for_b = features._brute_force(a, b)
    assert indices[0].tolist() == [1, 4] and distances[0, 0] == distances[0, 1]
    assert indices[1].tolist() == [1, 4]
    assert best_a_for_b[1] == 0 and best_a_for_b[4] == 0 and best_a_for_b[3] == 2
    # a tie is no distinctive match under the ratio test
    pairs = features.match_descriptors(a, b, ratio=0.8, mutual=False, method="brute")
    assert pairs.tolist() == [[2, 3]]


def test_rounding_below_zero_counts_as_zero():
    """‖a‖² + ‖b‖² − 2 a·b of identical large descriptors may round below 0."""
    a = np.full((2, 128), 255.0, np.float32)
    a[1, 0] = 0.0
    got = features._brute_force(a, a.copy())
    assert got[1][0, 0] >= 0.0 and got[1][1, 0] >= 0.0
    assert got[0][:, 0].tolist() == [0, 1] and got[2].tolist() == [0, 1]
