"""demtool.bundle.surface: heights of a reference DEM below body-fixed points."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.bundle.surface import ReferenceSurface, huber_cost, huber_weights
from demtool.maps import lonlat_height_to_xyz, xyz_to_lonlat_height
from tests.bundle import orbital


def _surface(spacing_m=500.0, noise_m=0.0, sigma=5.0):
    heights, transform, crs = orbital.reference_dem(spacing_m=spacing_m, noise_m=noise_m,
                                                    half_width_m=40e3)
    return ReferenceSurface(heights, transform, crs, orbital.RADIUS, sigma)


def test_dem_heights_follow_the_terrain_and_residuals_are_heights_above_it():
    surface = _surface(spacing_m=250.0)
    xyz = orbital.ground_points(400, half_width_m=35e3, seed=7)
    lon, lat, h = xyz_to_lonlat_height(xyz, radii=orbital.RADIUS)
    # bilinear between 250 m posts of hills of >= 7 km wavelength: error < 1 % of 1 km
    assert surface.dem_heights(xyz) == pytest.approx(h, abs=8.0)
    raised = lonlat_height_to_xyz(lon, lat, h + 30.0, radii=orbital.RADIUS)
    assert np.median(surface.residuals(raised)) == pytest.approx(30.0, abs=1.0)
    # off the DEM: NaN, not a height
    far = lonlat_height_to_xyz(lon + 5.0, lat, h, radii=orbital.RADIUS)
    assert np.isnan(surface.residuals(far)).all()


def test_gradient_is_up_minus_the_slope():
    """d(h − h_DEM)/dX = up − ∇h_DEM: a metre up raises the residual by a metre, a metre
    downhill raises it by the slope."""
    surface = _surface(spacing_m=100.0)
    xyz = orbital.ground_points(50, half_width_m=30e3, seed=8)
    _, gradient = surface.residuals_and_gradient(xyz)
    up = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    assert np.sum(gradient * up, axis=1) == pytest.approx(1.0, abs=0.02)
    east, north, _ = orbital._enu()
    lon, lat, _ = xyz_to_lonlat_height(xyz, radii=orbital.RADIUS)
    step = 20.0 / orbital.RADIUS * 180 / np.pi  # 20 m east in degrees (at the latitude)
    slope_e = (orbital.relief(lon + step / np.cos(np.radians(lat)), lat)
               - orbital.relief(lon - step / np.cos(np.radians(lat)), lat)) / 40.0
    assert gradient @ east == pytest.approx(-slope_e, abs=0.03)


def test_geographic_dem_gives_the_same_heights():
    from affine import Affine

    from demtool.maps import body_by_name

    crs = body_by_name("Moon").geographic_crs()
    lon0, lat0 = orbital.CENTRE_LONLAT
    step = 0.005
    n = 200
    transform = Affine(step, 0.0, lon0 - 0.5 * n * step, 0.0, -step, lat0 + 0.5 * n * step)
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    heights = orbital.relief(transform.c + cols * step, transform.f - rows * step)
    surface = ReferenceSurface(heights, transform, crs, orbital.RADIUS, 5.0)
    xyz = orbital.ground_points(200, half_width_m=12e3, seed=9)  # DEM: ±15 km
    assert np.abs(surface.residuals(xyz)).max() < 2.0  # bilinear over 150 m posts


def test_huber_loss_weights_and_cost():
    r = np.array([0.5, -1.0, 4.0, np.nan])
    assert huber_weights(r, 2.0) == pytest.approx([1.0, 1.0, 0.5, 0.0])
    assert huber_cost(r, 2.0) == pytest.approx(0.25 + 1.0 + (16.0 - 4.0))


def test_coarsened_dem_is_the_block_mean():
    """A pyramid level: 2 × 2 block means on posts twice as long; a block with fewer than
    half its posts on data is no data; heights at a point follow the coarse posts."""
    surface = _surface(spacing_m=100.0)
    heights = surface.heights.copy()
    heights[0, 0] = heights[0, 1] = heights[1, 0] = np.nan
    surface = ReferenceSurface(heights, surface.transform, surface.crs, surface.radius, 5.0)
    coarse = surface.coarsened(2, rows_per_chunk=7)
    assert coarse.transform.a == pytest.approx(200.0)
    assert np.isnan(coarse.heights[0, 0])
    assert coarse.heights[3, 5] == pytest.approx(heights[6:8, 10:12].mean())
    xyz = orbital.ground_points(200, half_width_m=30e3, seed=4)
    assert coarse.dem_heights(xyz) == pytest.approx(surface.dem_heights(xyz), abs=10.0)
    assert surface.coarsened(1) is surface


def test_interpolation_factor_measures_what_bilinear_misses():
    """A plane is interpolated exactly (factor 0); a random walk's relief between posts
    is missed by a fixed share of post × slope, whatever its amplitude."""
    from demtool.bundle.surface import interpolation_factor

    rows, cols = np.mgrid[0:40, 0:40].astype(float)
    assert interpolation_factor(30.0 * rows - 7.0 * cols) == pytest.approx(0.0, abs=1e-9)
    rng = np.random.default_rng(1)
    walk = np.cumsum(np.cumsum(rng.normal(size=(40, 40)), axis=0), axis=1)
    factor = interpolation_factor(walk)
    assert 0.05 < factor < 1.0
    assert interpolation_factor(100.0 * walk) == pytest.approx(factor)
    assert interpolation_factor(walk[:3, :3]) == 0.4  # too small to tell: the default


def test_point_sigmas_grow_with_post_spacing_and_slope():
    """σ² = sigma² + (factor · post · slope)²: flat ground keeps sigma, a 10 % slope under
    2 km posts at factor 0.25 adds 50 m."""
    import dataclasses

    surface = _surface(spacing_m=500.0)
    xyz = orbital.ground_points(200, half_width_m=30e3, seed=9)
    assert surface.point_sigmas(xyz) == pytest.approx(5.0)  # no post spacing: sigma alone
    coarse = dataclasses.replace(surface, post_m=2000.0, slope_factor=0.25)
    _, gradient = surface.residuals_and_gradient(xyz)
    up = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    slope = np.linalg.norm(gradient - np.sum(gradient * up, axis=1, keepdims=True) * up, axis=1)
    expected = np.sqrt(25.0 + (0.25 * 2000.0 * slope) ** 2)
    assert coarse.point_sigmas(xyz) == pytest.approx(expected, rel=1e-6)
    assert coarse.normalised_residuals(xyz) == pytest.approx(
        surface.residuals(xyz) / expected, abs=1e-9)
    # a coarse DEM on a slope weighs a tie point less than its quoted accuracy
    assert np.median(coarse.point_sigmas(xyz)) > 2 * 5.0


def test_curvature_error_is_bilinears_error_at_the_cell_centres():
    """On a quadratic, bilinear interpolation errs at a cell's centre by exactly
    h²/8 · (f_xx + f_yy) (second order is all there is); a plane and a saddle's xy term
    are reproduced exactly, and the bound holds where the curvatures differ in sign."""
    from demtool.bundle.surface import curvature_error
    from demtool.mapproject.core import bilinear_heights

    rows, cols = np.mgrid[0:12, 0:14].astype(float)

    def bowl(r, c):
        return 3.0 * r ** 2 + 1.5 * c ** 2 + 0.7 * r * c - 4.0 * r + 2.0 * c + 9.0

    centre_r, centre_c = rows[:-1, :-1] + 0.5, cols[:-1, :-1] + 0.5
    error = bowl(centre_r, centre_c) - bilinear_heights(bowl(rows, cols), centre_r, centre_c)
    bound = curvature_error(bowl(rows, cols))
    assert bound == pytest.approx(np.full(rows.shape, (6.0 + 3.0) / 8.0))
    assert np.abs(error) == pytest.approx(bound[:-1, :-1], abs=1e-9)
    assert curvature_error(5.0 * rows - 2.0 * cols + 0.3 * rows * cols) == pytest.approx(
        0.0, abs=1e-9)
    saddle = 3.0 * rows ** 2 - 1.5 * cols ** 2
    error = (3.0 * centre_r ** 2 - 1.5 * centre_c ** 2) - bilinear_heights(
        saddle, centre_r, centre_c)
    assert np.all(np.abs(error) <= curvature_error(saddle)[:-1, :-1] + 1e-9)
    assert curvature_error(np.ones((2, 5))) == pytest.approx(0.0)  # too short an axis


def test_interpolation_factor_leaves_to_the_curvature_what_it_explains():
    """A quadratic's held-out error is all curvature: no slope share; a random walk's
    relief between posts is not, and keeps one."""
    from demtool.bundle.surface import interpolation_factor

    rows, cols = np.mgrid[0:40, 0:40].astype(float)
    assert interpolation_factor(3.0 * rows ** 2 + 1.5 * cols ** 2 + 50.0 * rows) == 0.0
    rng = np.random.default_rng(2)
    walk = np.cumsum(rng.normal(size=(60, 60)), axis=0) + np.cumsum(
        rng.normal(size=(60, 60)), axis=1)
    assert 0.1 < interpolation_factor(walk) < 1.0


def test_point_sigmas_add_the_curvature_bound_on_crater_floors_not_on_planes():
    """σ² = sigma² + (factor · post · slope)² + curvature bound²: with no slope share a
    tie point on a planar slope keeps sigma, one on a crater's parabolic floor gets the
    bilinear bound of the floor's curvature."""
    import dataclasses

    from demtool.bundle.surface import curvature_error

    surface = _surface(spacing_m=500.0)
    rows, cols = np.indices(surface.heights.shape, dtype=float)
    n = surface.heights.shape[0]
    centre = (n - 1) / 2.0
    radius2 = (rows - centre) ** 2 + (cols - centre) ** 2
    inside = radius2 < (n / 6.0) ** 2
    heights = 0.1 * 500.0 * cols + np.where(inside, 20.0 * (radius2 - (n / 6.0) ** 2), 0.0)
    crater = dataclasses.replace(surface, heights=heights, post_m=500.0, slope_factor=0.0,
                                 curvature=curvature_error(heights))
    xyz = orbital.ground_points(400, half_width_m=35e3, seed=11)
    row, col = crater.pixels(xyz)
    distance2 = (row - centre) ** 2 + (col - centre) ** 2
    floor = distance2 < (n / 6.0 - 2.0) ** 2
    plane = distance2 > (n / 6.0 + 2.0) ** 2
    sigmas = crater.point_sigmas(xyz)
    assert floor.sum() > 10 and plane.sum() > 10
    assert sigmas[plane] == pytest.approx(5.0)  # bilinear reproduces the plane
    assert sigmas[floor] == pytest.approx(np.hypot(5.0, 2 * 40.0 / 8.0))  # f'' = 40 m/post²
    sloped = dataclasses.replace(crater, slope_factor=0.25)
    _, gradient = crater.residuals_and_gradient(xyz[plane])
    up = xyz[plane] / np.linalg.norm(xyz[plane], axis=1, keepdims=True)
    slope = np.linalg.norm(gradient - np.sum(gradient * up, axis=1, keepdims=True) * up, axis=1)
    assert sloped.point_sigmas(xyz[plane]) == pytest.approx(
        np.hypot(5.0, 0.25 * 500.0 * slope), rel=1e-6)
    # the pyramid levels of the registration carry their own curvature
    assert crater.coarsened(2).curvature.shape == crater.coarsened(2).heights.shape


def test_measuring_window_grows_a_small_footprint_to_the_factor_posts():
    from demtool.bundle.surface import FACTOR_POSTS, measuring_window

    assert measuring_window((10, 19, 100, 109), (240, 480)) == (0, FACTOR_POSTS, 84, 125)
    assert measuring_window((0, 5, 470, 480), (240, 480)) == (0, 41, 439, 480)
    assert measuring_window((3, 200, 7, 300), (240, 480)) == (3, 200, 7, 300)
    assert measuring_window((0, 5, 0, 5), (20, 30)) == (0, 20, 0, 30)  # the whole DEM
