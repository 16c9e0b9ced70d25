"""The k-nearest-neighbour statistics of the outlier test (demtool.dem.grid_kernels)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from demtool.dem.grid import local_median_statistics, row_medians
from demtool.dem.grid_kernels import MAX_BUCKET_SAMPLES, neighbour_statistics
from demtool.imaging.robust import NMAD_FACTOR


def kdtree_statistics(pixels, values, k, at=None):
    """What local_median_statistics computed before: scipy's KD-tree, (N, k) arrays."""
    queries = pixels if at is None else pixels[at]
    _, index = cKDTree(pixels).query(queries, k=k + 1)
    neighbour_values = values[index[:, 1:]]
    median = row_medians(neighbour_values)
    return median, NMAD_FACTOR * row_medians(np.abs(neighbour_values - median[:, None]))


def brute_force_statistics(pixels, values, k):
    """Every distance; the k nearest others, equal distances by lower index."""
    medians, nmads = [], []
    for query in range(len(pixels)):
        squared = ((pixels - pixels[query]) ** 2).sum(axis=1)
        order = np.lexsort((np.arange(len(pixels)), squared))
        nearest = order[order != query][:k]
        median = np.median(values[nearest])
        medians.append(median)
        nmads.append(NMAD_FACTOR * np.median(np.abs(values[nearest] - median)))
    return np.array(medians), np.array(nmads)


def warped_grid(rng, size, holes=0.05):
    """Pixel centres of a size² grid with holes through a homography: no equal distances."""
    rows, cols = np.mgrid[:size, :size]
    keep = rng.random((size, size)) > holes
    grid = np.column_stack([cols[keep], rows[keep], np.ones(keep.sum())])
    homography = np.array([[1.01, 0.013, 3.2], [-0.007, 0.995, -1.7],
                           [1.3e-5, -2.1e-5, 1.0]])
    mapped = grid @ homography.T
    return mapped[:, :2] / mapped[:, 2:]


@pytest.mark.parametrize("k", [3, 16, 17])
@pytest.mark.parametrize("threads", [1, 2])
def test_equal_to_the_kdtree_where_distances_are_distinct(k, threads):
    rng = np.random.default_rng(k)
    for pixels in (warped_grid(rng, 160),  # the disparity routes' samples
                   rng.random((30_000, 2)) * [900.0, 250.0],  # scattered tie points
                   rng.normal(size=(5000, 2)) * [40.0, 3.0]):  # uneven density
        values = rng.normal(size=len(pixels)) * 10.0
        values[rng.random(len(values)) < 0.01] += 500.0  # outliers
        found = neighbour_statistics(pixels, values, k, threads=threads)
        expected = kdtree_statistics(pixels, values, k)
        assert np.array_equal(found[0], expected[0])
        assert np.array_equal(found[1], expected[1])
        at = rng.choice(len(values), 300, replace=False)
        found_at = neighbour_statistics(pixels, values, k, at=at, threads=threads)
        assert np.array_equal(found_at[0], expected[0][at])
        assert np.array_equal(found_at[1], expected[1][at])


def test_equal_distances_go_to_the_lower_index():
    # an exact grid: the 16 nearest of an inner pixel are 12 within distance 2 and 4 of
    # the 8 at √5, which a KD-tree picks by the shape of its tree
    rng = np.random.default_rng(1)
    rows, cols = np.mgrid[:23, :19]
    keep = rng.random(rows.shape) > 0.1
    pixels = np.column_stack([cols[keep], rows[keep]]).astype(float)
    permutation = rng.permutation(len(pixels))  # indices not in grid order
    pixels = pixels[permutation]
    values = rng.normal(size=len(pixels))
    for k in (16, 5, 8):
        found = neighbour_statistics(pixels, values, k, threads=2)
        expected = brute_force_statistics(pixels, values, k)
        assert np.array_equal(found[0], expected[0])
        assert np.array_equal(found[1], expected[1])


def test_degenerate_layouts():
    rng = np.random.default_rng(2)
    line = np.column_stack([np.sort(rng.random(400)) * 1e4, np.full(400, 7.0)])
    diagonal = np.repeat(np.arange(50.0)[:, None], 2, axis=1) * 1e-6
    pair = np.array([[0.0, 0.0], [3.0, 4.0]])
    for pixels, k in ((line, 16), (diagonal, 6), (pair, 1)):
        values = rng.normal(size=len(pixels))
        found = neighbour_statistics(pixels, values, k)
        expected = brute_force_statistics(pixels, values, k)
        assert np.array_equal(found[0], expected[0])
        assert np.array_equal(found[1], expected[1])


def test_a_nan_value_gives_nan_statistics_like_np_median():
    rng = np.random.default_rng(3)
    pixels = rng.random((200, 2)) * 20.0
    values = rng.normal(size=200)
    values[17] = np.nan
    found = neighbour_statistics(pixels, values, 8)
    expected = kdtree_statistics(pixels, values, 8)
    assert np.array_equal(np.isnan(found[0]), np.isnan(expected[0]))
    assert np.isnan(found[0]).any()
    finite = ~np.isnan(expected[0])
    assert np.array_equal(found[0][finite], expected[0][finite])


def test_crowded_positions_go_to_the_kdtree():
    # samples piled on three spots: buckets would hold hundreds each
    rng = np.random.default_rng(4)
    spots = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 800.0]])
    pixels = spots[rng.integers(0, 3, 3 * MAX_BUCKET_SAMPLES)] + rng.normal(
        size=(3 * MAX_BUCKET_SAMPLES, 2)) * 1e-3
    values = rng.normal(size=len(pixels))
    assert neighbour_statistics(pixels, values, 16) is None
    median, nmad = local_median_statistics(pixels, values, neighbours=16)
    expected = kdtree_statistics(pixels, values, 16)
    assert np.array_equal(median, expected[0]) and np.array_equal(nmad, expected[1])


def test_a_dense_cluster_in_a_wide_field_goes_to_the_kdtree(monkeypatch):
    # most samples in a spot 1/1000 of the field's width: buckets sized for the mean
    # density would hold them all (Σ occupancy² decides, whatever the largest bucket)
    import demtool.dem.grid_kernels as kernels

    monkeypatch.setattr(kernels, "MAX_BUCKET_SAMPLES", 10**9)
    rng = np.random.default_rng(5)
    pixels = np.concatenate([rng.random((200, 2)) * 5000.0,
                             2500.0 + rng.random((6000, 2)) * 5.0])
    values = rng.normal(size=len(pixels))
    assert neighbour_statistics(pixels, values, 16) is None
    median, nmad = local_median_statistics(pixels, values, neighbours=16)
    expected = kdtree_statistics(pixels, values, 16)
    assert np.array_equal(median, expected[0]) and np.array_equal(nmad, expected[1])
