"""Raw image coordinates of scattered map cells on a lattice (demtool/mapproject/lattice.py)
against the exact projection of every cell: within the tolerance, the same cells seen,
NaN heights kept NaN, any row order and any thread count giving the same values; and
dem --mapprojected's map placement of the points (demtool.dem.sensors.points_on_map)
equal to the grid and map coordinates computed apart."""

import numpy as np
import pytest

from demtool.mapproject import core as mp
from demtool.mapproject import threads
from demtool.mapproject.lattice import points_image_coordinates
from demtool.mapproject.stereo import map_cells_xy, raw_coordinates
from demtool.maps import map_to_lonlat, map_to_xyz, snap_grid
from tests.helpers.linescan import MOON, linescan_sensor, ortho_ray_case, terrain


@pytest.fixture(scope="module")
def scene():
    sensor = linescan_sensor(lines=300, samples=200, roll_deg=12.0)
    g = mp.ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(g.crs, *g.bounds(), 1.0)
    rng = np.random.default_rng(3)
    # the left cells of a disparity (row by row) and right cells col − d (fractional),
    # some beyond the image's edge
    rows, cols = np.nonzero(rng.random(grid.shape) < 0.5)
    rows, cols = rows.astype(np.float64), cols - rng.uniform(-3.0, 12.0, cols.size)
    heights = terrain(*map_to_lonlat(grid.crs, *map_cells_xy(grid.transform, rows, cols)))
    xyz = map_to_xyz(grid.crs, *map_cells_xy(grid.transform, rows, cols), heights)
    exact = sensor.ground_to_image(np.asarray(xyz).reshape(-1, 3))
    return sensor, grid, rows, cols, heights, exact


def test_lattice_coordinates_match_the_exact_projection_within_the_tolerance(scene):
    sensor, grid, rows, cols, heights, (line, sample) = scene
    got = points_image_coordinates(sensor, grid.crs, grid.transform, rows, cols, heights,
                                   strip_rows=40, tolerance=1e-4)
    assert np.array_equal(np.isnan(got.line), np.isnan(line))
    assert np.isfinite(line).mean() > 0.9
    error = np.hypot(got.line - line, got.sample - sample)
    assert 0 < got.max_error_px <= 1e-4
    # the tolerance is checked at random points; every point is within 3x of it here
    assert np.nanmax(error) <= 3e-4
    assert got.exact_points < 0.2 * rows.size  # the lattice did the work
    # tolerance 0: every point projected exactly, the exact values
    exact = raw_coordinates(sensor, grid.crs, grid.transform, rows, cols, heights,
                            tolerance=0.0)
    assert exact.exact_points == np.isfinite(heights).sum()
    assert np.array_equal(exact.line, line, equal_nan=True)
    assert np.array_equal(exact.sample, sample, equal_nan=True)
    # a tolerance no lattice meets: exact projection of every point
    strict = points_image_coordinates(sensor, grid.crs, grid.transform, rows, cols, heights,
                                      strip_rows=40, tolerance=1e-12)
    assert strict.exact_points == rows.size
    assert np.array_equal(strict.line, line, equal_nan=True)


def test_lattice_coordinates_do_not_depend_on_row_order_threads_or_nan(scene, monkeypatch):
    sensor, grid, rows, cols, heights, _ = scene
    holes = heights.copy()
    holes[::7] = np.nan
    runs = []
    for count in (1, 2):
        monkeypatch.setattr(threads, "available_threads", lambda count=count: count)
        runs.append(points_image_coordinates(sensor, grid.crs, grid.transform, rows, cols,
                                             holes, strip_rows=40))
    one, two = runs
    assert np.array_equal(one.line, two.line, equal_nan=True)
    assert np.array_equal(one.sample, two.sample, equal_nan=True)
    assert np.isnan(one.line[::7]).all() and np.isnan(one.sample[::7]).all()
    order = np.random.default_rng(0).permutation(rows.size)
    shuffled = points_image_coordinates(sensor, grid.crs, grid.transform, rows[order],
                                        cols[order], holes[order], strip_rows=40)
    # the same lattices; other check points (exact there): within the tolerance
    assert np.array_equal(np.isnan(shuffled.line), np.isnan(one.line[order]))
    np.testing.assert_allclose(shuffled.line, one.line[order], atol=3e-4)
    np.testing.assert_allclose(shuffled.sample, one.sample[order], atol=3e-4)


def test_points_on_map_equal_the_grid_and_coordinates_computed_apart():
    from demtool.dem.sensors import points_on_map
    from demtool.maps.frames import xyz_to_lonlat_height
    from demtool.maps.grids import grid_from_xyz
    from demtool.maps.projections import lonlat_to_map

    sensor = linescan_sensor(lines=120, samples=100)
    line, sample = np.meshgrid(np.arange(0.5, 120), np.arange(0.5, 100), indexing="ij")
    xyz = sensor.image_to_ground(line.ravel(), sample.ravel(), 5.0)
    placed = points_on_map(xyz, MOON, gsd_m=1.5)
    grid = grid_from_xyz(MOON, xyz, 1.5)
    assert placed.grid.transform == grid.transform and placed.grid.shape == grid.shape
    lon, lat, height = xyz_to_lonlat_height(xyz, radii=MOON.surface)
    x, y = lonlat_to_map(grid.crs, lon, lat)
    assert np.array_equal(placed.x, x) and np.array_equal(placed.y, y)
    assert np.array_equal(placed.height, height)


def test_ortho_rays_triangulate_as_the_exact_raw_pixels_rays():
    """dem --mapprojected's rays (origin interpolated on the lattice, through the cell's
    ground point) give the points the exact raw pixels' image_to_ray rays give."""
    from demtool.dem.ortho_rays import ortho_rays
    from demtool.dem.sensors import triangulate_ground_rays, triangulate_sensors

    left, right, grid, orthos, heights, rows, cols, r_cols = ortho_ray_case(160, 140)
    found = ortho_rays(*orthos, grid.crs, rows, cols, rows, r_cols)
    assert found.seen.mean() > 0.5
    assert found.max_error_px() <= 1e-4 and found.left.exact_points < 0.3 * rows.size
    got = triangulate_ground_rays(*found.rays())
    pixels = []
    for s, c in ((left, cols), (right, r_cols)):
        x, y = map_cells_xy(grid.transform, rows, c)
        xyz = np.asarray(map_to_xyz(grid.crs, x, y, heights(x, y))).reshape(-1, 3)
        line, sample = s.ground_to_image(xyz)
        pixels += [line[found.seen], sample[found.seen]]
    want = triangulate_sensors(left, right, *pixels)
    assert np.isfinite(want.xyz).all()
    np.testing.assert_allclose(got.xyz, want.xyz, rtol=0, atol=1e-3)  # metres
    np.testing.assert_allclose(got.gap, want.gap, rtol=0, atol=1e-3)
    assert np.array_equal(got.in_front, want.in_front)
