"""Tests of the fast paths of `match`: IC-GN LSM, the triangle raster, grid spacing."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.match import SeedTriangulation, lsm_match, match
from demtool.match.lsm_base import CONVERGED
from tests.helpers.match import textured_pair


def _lsm_both(left, right, truth, rows, cols, **options):
    start = cols - np.round(truth[rows, cols]) + 0.3  # about a pixel off, as from NCC
    return {method: lsm_match(left, right, rows, cols, start, rows.astype(float),
                              template=15, method=method, **options)
            for method in ("inverse", "forward")}


@pytest.mark.parametrize("weighting", [0.0, 3.0])
def test_inverse_compositional_lsm_agrees_with_gruens_form(weighting):
    left, right, truth = textured_pair(96, 128, seed=3, noise=0.01)
    rows, cols = np.meshgrid(np.arange(12, 84, 5), np.arange(24, 116, 5), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    results = _lsm_both(left, right, truth, rows, cols, weighting=weighting)
    inverse, forward = results["inverse"], results["forward"]
    both = (inverse.status == CONVERGED) & (forward.status == CONVERGED)
    assert both.mean() > 0.95
    d_inverse = cols - inverse.x_right
    d_forward = cols - forward.x_right
    # the same maximum of the correlation: positions and correlations agree
    assert np.max(np.abs(d_inverse[both] - d_forward[both])) < 0.02
    gap = np.abs(inverse.correlation[both] - forward.correlation[both])
    assert np.median(gap) < 1e-4 and gap.max() < 0.02
    # both are right against the truth (smooth field: the template's mean slope)
    assert np.mean(np.abs(d_inverse[both] - truth[rows, cols][both])) < 0.03
    # sigma: the same order as Grün's (template-side instead of window-side gradients)
    ratio = np.median(inverse.sigma_x[both] / forward.sigma_x[both])
    assert 0.5 < ratio < 2.0


def test_lsm_rejects_an_unknown_method():
    image = np.random.default_rng(0).normal(size=(40, 40))
    with pytest.raises(ValueError, match="method must be one of forward, inverse"):
        lsm_match(image, image, np.array([20]), np.array([20]), np.array([20.0]),
                  np.array([20.0]), method="newton")


def test_triangle_raster_equals_qhull_point_location():
    rng = np.random.default_rng(4)
    points = rng.uniform(10, 190, (300, 2))
    tri = SeedTriangulation(points, rng.normal(size=300))
    np.testing.assert_allclose(tri.transform, tri.delaunay.transform, atol=1e-9)
    yy, xx = np.mgrid[0:200:3, 0:210:2]
    x, y = xx.ravel().astype(float), yy.ravel().astype(float)
    raster = tri.evaluate(x, y)  # integer points: the numba raster
    qhull = tri.evaluate(x + 1e-9, y)  # fractional: scipy's find_simplex
    assert raster.inside.sum() > 0.5 * x.size and (~raster.inside).sum() > 100
    np.testing.assert_array_equal(raster.inside, qhull.inside)
    np.testing.assert_allclose(raster.disparity, qhull.disparity, atol=1e-6)
    # a vertex-disparity bound may differ only on an edge shared by two triangles
    assert np.mean(raster.low == qhull.low) > 0.99
    # a plane is interpolated exactly inside the hull
    plane = SeedTriangulation(points, 2.0 + 0.01 * points[:, 0] - 0.02 * points[:, 1])
    bounds = plane.evaluate(x, y)
    expected = 2.0 + 0.01 * x - 0.02 * y
    np.testing.assert_allclose(bounds.disparity[bounds.inside], expected[bounds.inside],
                               atol=1e-9)


def _step(x, y):
    return np.where(y < 48, 4.0, 10.0) + 0.0 * x


def test_grid_spacing_does_not_interpolate_across_a_disparity_step():
    left, right, truth = textured_pair(96, 128, seed=5, disparity=_step)
    every = match(left, right, template=13, threshold=0.9, grid_spacing=1)
    coarse = match(left, right, template=13, threshold=0.9, grid_spacing=2)
    ok = np.isfinite(coarse.disparity)
    errors = np.abs(coarse.disparity[ok] - truth[ok])
    # no pixel gets a value between the two levels (an interpolation across the step)
    assert np.mean(errors > 1.0) < 0.005
    assert errors.mean() < 0.1
    # the rows next to the step are matched as completely as with every pixel matched
    band = np.zeros_like(ok)
    band[40:57, 20:-8] = True
    assert ok[band].sum() >= 0.97 * np.isfinite(every.disparity)[band].sum()
    between = coarse.summary["between_nodes"]
    assert between["matched"] > 0 and between["accepted"] > 0
    assert between["interpolated"] > 0.5 * left.size
    assert every.summary["between_nodes"] is None
    assert abs(coarse.completeness - every.completeness) < 2.0


def test_row_matching_equals_brute_force_matching_then_the_row_filter():
    from demtool.imaging import features
    from demtool.match.seeds import match_on_rows

    rng = np.random.default_rng(6)
    n, true = 600, 420
    points_left = np.column_stack([rng.uniform(0, 400, n), rng.uniform(0, 300, n)])
    descriptors_left = rng.uniform(0, 100, (n, 128)).astype(np.float32)
    points_right = points_left + [-15.0, 0.4]
    descriptors_right = descriptors_left + rng.normal(0, 6, (n, 128)).astype(np.float32)
    points_right[true:] = np.column_stack([rng.uniform(0, 400, n - true),
                                           rng.uniform(0, 300, n - true)])
    descriptors_right[true:] = rng.uniform(0, 100, (n - true, 128))
    pairs = match_on_rows(points_left, descriptors_left, points_right, descriptors_right,
                          max_vertical=1.5)
    reference = features.match_descriptors(descriptors_left, descriptors_right, ratio=0.8)
    same_row = np.abs(points_left[reference[:, 0], 1] - points_right[reference[:, 1], 1])
    reference = reference[same_row <= 1.5]
    # distinctive descriptors: the row band changes nothing but the work
    np.testing.assert_array_equal(pairs, reference)
    assert len(pairs) >= 0.95 * true and np.all(pairs[:, 0] == pairs[:, 1])
    assert match_on_rows(points_left[:0], descriptors_left[:0], points_right,
                         descriptors_right, max_vertical=1.5).shape == (0, 2)
