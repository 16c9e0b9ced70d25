"""`demtool dem`: points route, disparity routes, grid helpers, projective fit, errors."""

from __future__ import annotations

import numpy as np
import pytest

from demtool import dem as core
from demtool.bundle import BundleResult, apply_similarity
from demtool.errors import ProcessingError
from tests.helpers.dem import (
    ALTITUDE,
    BASELINE,
    RECTIFY,
    nadir_camera,
    surface,
    synthetic_disparity,
    truth_grid,
)


def test_splat_median_takes_the_median_per_cell():
    pixels = np.array([[1.2, 0.9], [0.8, 1.1], [1.0, 1.4], [3.0, 2.0], [-5.0, 0.0],
                       [2.0, 2.0]])
    values = np.array([1.0, 5.0, 2.0, 7.0, 100.0, np.nan])
    grid, counts = core.splat_median(pixels, values, (3, 4))
    assert grid[1, 1] == 2.0 and counts[1, 1] == 3
    assert grid[2, 3] == 7.0
    assert np.isnan(grid[2, 2]) and counts.sum() == 4  # outside and NaN samples ignored
    grid, _ = core.splat_median(pixels[:2], values[:2], (3, 4))
    assert grid[1, 1] == 3.0  # even count: mean of the middle two


def test_splat_bilinear_resamples_a_plane():
    # Samples on a slightly rotated and scaled lattice, as disparities mapped back
    # through a rectification homography are.
    lattice = np.stack(np.meshgrid(np.arange(-5, 40), np.arange(-5, 40)), -1).reshape(-1, 2)
    angle = 0.05
    A = 0.97 * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    pixels = lattice @ A.T + [0.31, -0.27]
    values = 0.3 * pixels[:, 0] - 0.7 * pixels[:, 1] + 4.0
    grid, weight = core.splat_bilinear(pixels, values, (32, 32))
    rows, cols = np.mgrid[:32, :32]
    truth = 0.3 * cols - 0.7 * rows + 4.0
    np.testing.assert_allclose(grid, truth, atol=0.02)
    assert weight.min() > 0.5
    on_grid = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    exact, _ = core.splat_bilinear(on_grid, truth.ravel(), (32, 32))
    np.testing.assert_allclose(exact, truth, atol=1e-12)
    empty, _ = core.splat_bilinear(np.array([[5.0, 5.0]]), np.array([1.0]), (32, 32))
    assert np.isfinite(empty).sum() == 1


def test_local_median_test_rejects_spikes_only():
    rng = np.random.default_rng(1)
    pixels = rng.uniform(0, 100, (2000, 2))
    heights = 0.05 * pixels[:, 0] + rng.normal(0, 0.05, 2000)
    spikes = rng.choice(2000, 30, replace=False)
    heights[spikes] += rng.choice([-5.0, 5.0], 30)
    keep = core.local_median_inliers(pixels, heights, neighbours=16, threshold=3.0)
    assert not keep[spikes].any()
    assert keep.sum() >= 2000 - 30 - 20  # few false rejections
    assert core.local_median_inliers(pixels, heights, threshold=0).all()


def test_fill_and_smooth_marks_interpolated_cells_and_checks_median():
    measured = np.full((20, 20), np.nan)
    measured[::4, ::4] = 1.0
    filled = core.fill_and_smooth(measured, median_px=3)
    assert np.isfinite(filled.dem).all()
    np.testing.assert_allclose(filled.dem, 1.0)
    assert filled.interpolated.sum() == 400 - 25
    with pytest.raises(ProcessingError, match="no measured height"):
        core.fill_and_smooth(np.full((5, 5), np.nan))
    with pytest.raises(Exception, match="odd"):
        core.fill_and_smooth(measured, median_px=4)


def bundle_points(n: int = 4000, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-22, 22, (n, 2))  # inside the 48 m footprint
    return np.column_stack([xy, surface(xy[:, 0], xy[:, 1])])


def test_eq2_heights():
    depth = np.array([9.0, 10.0, 11.0])  # model units, mean 10
    np.testing.assert_allclose(core.heights_from_relative_depth(depth, 500.0),
                               [50.0, 0.0, -50.0])


def test_points_route_metric_reproduces_the_paraboloid():
    camera = nadir_camera()
    points = bundle_points()
    result = core.dem_from_points(points, camera, aligned=True)
    truth = truth_grid(camera)
    inner = np.s_[12:-12, 12:-12]  # inside the points' footprint (±22 m = ±44 px)
    error = result.dem[inner] - truth[inner]
    assert np.abs(error).max() < 0.05  # metres, relief ~ 3 m
    assert result.report["points_in_target"] == len(points)
    assert result.interpolated.sum() > 0 and (~result.interpolated).sum() > 1000


def test_points_route_eq2_in_an_arbitrary_model_frame():
    camera = nadir_camera()
    points = bundle_points()
    truth_result = BundleResult(points=points, colors=np.zeros(len(points)),
                                track_length=np.full(len(points), 2),
                                reprojection_error=np.zeros(len(points)),
                                image_names=np.array(["view_00"]), cameras=[camera],
                                distortion=np.zeros((1, 2)), target_index=0)
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    model = apply_similarity(truth_result, 0.013, rotation, np.array([3.0, -1.0, 0.5]))
    result = core.dem_from_points(model.points, model.cameras[0], aligned=False,
                                  distance_m=ALTITUDE)
    truth = truth_grid(camera)
    inner = np.s_[12:-12, 12:-12]
    error = result.dem[inner] - truth[inner]
    # eq. 2 gives heights relative to the mean depth: compare after removing the offset.
    assert np.abs(error - np.median(error)).max() < 0.06


def test_points_route_errors():
    camera = nadir_camera()
    behind = bundle_points(50) + np.array([0.0, 0.0, 2 * ALTITUDE])
    with pytest.raises(ProcessingError, match="none of the 50 points"):
        core.dem_from_points(behind, camera, aligned=True)
    with pytest.raises(ProcessingError, match="only 5 bundle points"):
        core.dem_from_points(bundle_points(5), camera, aligned=True)


def test_calibrated_disparity_route_reproduces_heights():
    left, right = nadir_camera(), nadir_camera(BASELINE)
    disparity = synthetic_disparity(left, right)
    result = core.dem_from_disparity_calibrated(disparity, RECTIFY, RECTIFY, left, right)
    truth = truth_grid(left)
    measured = ~result.interpolated
    assert measured.mean() > 0.6
    inner = np.zeros_like(measured)
    inner[3:-3, 3:-3] = True
    assert np.abs(result.dem - truth)[measured & inner].max() < 0.01
    # Only the strip the right image does not see (about 24 px on the left) is filled.
    assert np.isfinite(result.dem).all()
    assert np.nonzero(result.interpolated[3:-3, 3:-3])[1].max() + 3 < 30
    assert result.report["ray_distance_median_m"] < 1e-6


def test_projective_fit_recovers_a_known_transform():
    rng = np.random.default_rng(3)
    T = np.array([[1.1, 0.05, 0.0, 3.0], [-0.02, 0.95, 0.01, -2.0], [0.0, 0.0, -40.0, 9.0],
                  [0.0, 0.0, 0.02, 1.0]])
    source = np.column_stack([rng.uniform(0, 200, 500), rng.uniform(0, 200, 500),
                              rng.uniform(10, 30, 500)])
    target = core.apply_projective_3d(T, source)
    fit = core.fit_projective_3d(source, target)
    np.testing.assert_allclose(fit.T / fit.T[3, 3], T, rtol=1e-6, atol=1e-8)
    # 20 % gross outliers in the heights do not move it.
    corrupted = target.copy()
    bad = rng.choice(500, 100, replace=False)
    corrupted[bad, 2] += rng.normal(0, 50, 100)
    target_noisy = corrupted + np.column_stack([np.zeros((500, 2)), rng.normal(0, 0.01, 500)])
    fit = core.fit_projective_3d(source, target_noisy, seed=1)
    mapped = core.apply_projective_3d(fit.T, source)
    assert np.abs(mapped[:, 2] - target[:, 2]).max() < 0.1
    assert not fit.inliers[bad].any() or fit.inliers[bad].mean() < 0.05
    with pytest.raises(ProcessingError, match="at least 5"):
        core.fit_projective_3d(source[:4], target[:4])


def test_projective_disparity_route_matches_reference_datum():
    left, right = nadir_camera(), nadir_camera(BASELINE)
    disparity = synthetic_disparity(left, right)
    truth = truth_grid(left)
    reference = truth + 5.0  # another datum: the fit carries it over
    reference[:20, :20] = np.nan  # holes in the reference do not matter
    result = core.dem_from_disparity_projective(disparity, RECTIFY, RECTIFY, reference)
    measured = ~result.interpolated
    inner = np.zeros_like(measured)
    inner[3:-3, 3:-3] = True
    assert np.abs(result.dem - (truth + 5.0))[measured & inner].max() < 0.02
    assert result.report["fit_inliers"] > 0.9 * result.report["fit_points"]


def test_disparity_route_rejects_nan_only_disparity():
    with pytest.raises(ProcessingError, match="no valid pixel"):
        core.dem_from_disparity_calibrated(np.full((10, 10), np.nan), np.eye(3), np.eye(3),
                                           nadir_camera(), nadir_camera(BASELINE))


def test_calibrated_disparity_route_drops_points_behind_the_cameras():
    """Negative disparities (rays diverging: the point lies behind both cameras) must not
    become heights; they are counted and the hole is filled from the neighbours."""
    left, right = nadir_camera(), nadir_camera(BASELINE)
    disparity = synthetic_disparity(left, right)
    block = (slice(30, 40), slice(50, 70))
    bad = np.isfinite(disparity[block]).sum()
    assert bad > 100
    disparity[block] = -np.abs(disparity[block])
    result = core.dem_from_disparity_calibrated(disparity, RECTIFY, RECTIFY, left, right)
    assert result.report["behind_camera"] == bad
    truth = truth_grid(left)
    hole = (slice(28, 36), slice(47, 64))  # the block in the original image (RECTIFY⁻¹)
    assert result.interpolated[hole].all()
    assert np.abs(result.dem - truth)[hole].max() < 0.05


def test_screen_triangulation_counts_behind_and_gap():
    from demtool.dem.disparity import screen_triangulation

    left, right = nadir_camera(), nadir_camera(BASELINE)
    ahead = left.center + np.array([[0.0, 0.0, -100.0]]) * np.ones((10, 1))
    behind = left.center + np.array([[0.0, 0.0, 50.0]]) * np.ones((3, 1))
    points = np.vstack([ahead, behind])
    gap = np.r_[np.full(9, 0.01), 5.0, np.zeros(3)]
    depth = left.depth(points)
    assert (depth[:10] > 0).all() and (depth[10:] < 0).all()
    screened = screen_triangulation(points, gap, left, right, max_ray_gap=1.0)
    assert screened.behind == 3 and screened.rejected_gap == 1
    assert screened.keep.sum() == 9


@pytest.mark.parametrize("k", [1, 2, 3, 16, 17])
def test_row_medians_are_numpys_bit_for_bit(k):
    from demtool.dem.grid import row_medians

    rng = np.random.default_rng(k)
    values = rng.normal(0.0, 1000.0, (500, k))
    values[7] = 3.0  # ties
    values[8, : (k + 1) // 2] = -np.inf  # infinities go through np.median
    assert np.array_equal(row_medians(values), np.median(values, axis=1))
    values[9, 0] = np.nan
    found = row_medians(values)
    assert np.isnan(found[9]) and np.array_equal(found[:9], np.median(values[:9], axis=1))


def test_local_median_statistics_do_not_depend_on_the_threads():
    """The neighbour search follows the context's thread limit (a tile job's threads) and
    finds the same neighbours on one thread as on all (ties of a regular grid included)."""
    from demtool.dem.grid import local_median_statistics
    from demtool.tiling.distributed import threads_limited, usable_threads

    rows, cols = np.mgrid[0:60, 0:70]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(np.float64)
    heights = np.random.default_rng(3).normal(0.0, 1.0, len(pixels))
    with threads_limited(1):
        assert usable_threads() == 1
        one = local_median_statistics(pixels, heights)
    every = local_median_statistics(pixels, heights)
    assert all(np.array_equal(a, b) for a, b in zip(one, every, strict=True))
