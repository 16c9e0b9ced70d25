"""Nearest neighbours both ways in one pass over each block of the distance matrix
(demtool.imaging.nearest), against the numpy formula it replaced."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.imaging import features


def numpy_brute_force(a, b, chunk_bytes=64 << 20):
    """The previous implementation: argpartition along rows, argmin down columns."""
    norms_b = np.einsum("ij,ij->i", b, b)
    indices = np.full((len(a), 2), -1, np.int64)
    distances = np.full((len(a), 2), np.inf, np.float64)
    best_a_for_b = np.zeros(len(b), np.int64)
    best_b_distance = np.full(len(b), np.inf, np.float64)
    rows = max(1, chunk_bytes // (4 * len(b)))
    for start in range(0, len(a), rows):
        block = a[start:start + rows]
        d2 = np.einsum("ij,ij->i", block, block)[:, None] + norms_b[None, :] - 2.0 * (block @ b.T)
        np.maximum(d2, 0.0, out=d2)
        k = min(2, len(b))
        nearest = np.argpartition(d2, k - 1, axis=1)[:, :k] if len(b) > k else \
            np.tile(np.arange(k), (len(block), 1))
        nearest_d = np.take_along_axis(d2, nearest, axis=1)
        order = np.argsort(nearest_d, axis=1)
        indices[start:start + len(block), :k] = np.take_along_axis(nearest, order, axis=1)
        distances[start:start + len(block), :k] = np.take_along_axis(nearest_d, order, axis=1)
        column_best = np.argmin(d2, axis=0)
        column_d = d2[column_best, np.arange(len(b))]
        better = column_d < best_b_distance
        best_b_distance[better] = column_d[better]
        best_a_for_b[better] = column_best[better] + start
    return indices, distances, best_a_for_b


@pytest.mark.parametrize(("n_a", "n_b", "chunk_bytes"), [(300, 500, 64 << 20),
                                                         (300, 500, 4 * 500 * 7),
                                                         (40, 1, 64 << 20),
                                                         (40, 2, 64 << 20),
                                                         (1, 3, 64 << 20)])
def test_the_same_neighbours_and_distances_as_numpy(n_a, n_b, chunk_bytes):
    """Random descriptors (no ties), one block or blocks of 7 rows, and the small sets
    where ``b`` has one or two rows."""
    rng = np.random.default_rng(n_a + n_b)
    a = rng.uniform(0, 100, (n_a, 128)).astype(np.float32)
    b = rng.uniform(0, 100, (n_b, 128)).astype(np.float32)
    b[: min(n_b, n_a) // 2] = a[: min(n_b, n_a) // 2] + 0.5  # some near pairs
    got = features._brute_force(a, b, chunk_bytes)
    expected = numpy_brute_force(a, b, chunk_bytes)
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
