"""The core of `demtool mapproject`: bicubic resampling, the interpolated map → image
projection, grids, angles and DEM sampling, against closed forms and the exact model."""

import numpy as np
import pytest

from demtool.mapproject import core as mp
from demtool.maps import grid_lonlat, lonlat_height_to_xyz, snap_grid
from tests.helpers.linescan import MOON, R, linescan_sensor, terrain


@pytest.fixture(scope="module")
def sensor():
    return linescan_sensor(lines=300, samples=200, roll_deg=12.0)


@pytest.fixture(scope="module")
def grid(sensor):
    g = mp.ortho_grid(sensor, MOON, height=0.0)
    return snap_grid(g.crs, *g.bounds(), 1.0)


def test_bicubic_reproduces_quadratics_and_propagates_nan():
    rows, cols = np.mgrid[0:20, 0:30].astype(np.float64)
    image = 0.3 * rows**2 - 0.2 * rows * cols + 0.1 * cols**2 + 2 * rows - cols + 5
    rng = np.random.default_rng(1)
    r = rng.uniform(1, 17, 500)
    c = rng.uniform(1, 27, 500)
    got = mp.bicubic_sample(image, r, c)
    want = 0.3 * r**2 - 0.2 * r * c + 0.1 * c**2 + 2 * r - c + 5
    # Keys' kernel (a = -0.5) is exact for quadratics; float32 output
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=2e-4)
    # at the pixel centres it returns the pixels themselves
    np.testing.assert_allclose(mp.bicubic_sample(image, rows[3:5, 4:6], cols[3:5, 4:6]),
                               image[3:5, 4:6], rtol=1e-6)
    holed = image.copy()
    holed[10, 10] = np.nan
    out = mp.bicubic_sample(holed, np.array([10.4, 10.0, 5.0, np.nan]),
                            np.array([9.5, 12.9, 5.0, 3.0]))
    assert np.isnan(out[0]) and np.isnan(out[3])
    assert np.isfinite(out[1])  # rows 9..12, columns 11..14: no NaN among them
    assert out[2] == pytest.approx(image[5, 5], rel=1e-6)


def test_native_gsd_and_footprint(sensor):
    nadir = linescan_sensor(lines=100, samples=100, gsd=2.0)
    assert mp.native_gsd(nadir, R, 0.0) == pytest.approx(2.0, rel=1e-6)
    # rolled 12 degrees: cross-track pixels are longer by about 1 / cos^2(12 deg)
    along_across = mp.native_gsd(sensor, R, 0.0) ** 2
    assert along_across == pytest.approx(1.0 / np.cos(np.radians(12.0)) ** 2, rel=0.02)
    xyz = mp.ground_footprint(sensor, R, 0.0, per_edge=4)
    assert xyz.shape == (16, 3)
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), R, rtol=1e-12)
    line, sample = sensor.ground_to_image(xyz)
    border_line, border_sample = mp._border(sensor.lines, sensor.samples, 4)
    np.testing.assert_allclose(line, border_line, atol=1e-4)
    np.testing.assert_allclose(sample, border_sample, atol=1e-4)


def test_ortho_grid_covers_footprint_at_native_gsd(sensor):
    grid = mp.ortho_grid(sensor, MOON, height=0.0)
    assert grid.gsd[0] == pytest.approx(mp.native_gsd(sensor, R), rel=1e-9)
    from demtool.maps import xyz_to_map

    x, y, _ = xyz_to_map(grid.crs, mp.ground_footprint(sensor, R, 0.0))
    xmin, ymin, xmax, ymax = grid.bounds()
    assert (x >= xmin).all() and (x <= xmax).all() and (y >= ymin).all() and (y <= ymax).all()
    assert xmax - xmin < x.max() - x.min() + 2 * grid.gsd[0]
    box = mp.ortho_grid(sensor, MOON, gsd=5.0, bounds=(9.99, 4.99, 10.01, 5.01))
    assert box.gsd[0] == 5.0
    width_m = np.radians(0.02) * R * np.cos(np.radians(5.0))
    assert box.width == pytest.approx(width_m / 5.0, abs=2)


def test_image_coordinates_match_exact_projection(sensor, grid):
    window = (40, 140, 30, 150)
    rows, cols = np.mgrid[40:140, 30:150]
    lon, lat = grid_lonlat(grid)
    heights = terrain(lon, lat)[40:140, 30:150]
    got = mp.image_coordinates(sensor, grid.crs, grid.transform, window, heights, step=16,
                               tolerance=0.01)
    assert got.step >= 2  # the lattice was enough
    xyz = lonlat_height_to_xyz(lon[40:140, 30:150], lat[40:140, 30:150], heights, radii=R)
    line, sample = sensor.ground_to_image(xyz)
    err = np.hypot(got.line - line, got.sample - sample)
    assert np.nanmax(err) < 0.02
    assert got.max_error_px <= 0.01
    # a tolerance no lattice meets falls back to exact evaluation
    exact = mp.image_coordinates(sensor, grid.crs, grid.transform, window, heights, step=16,
                                 tolerance=1e-12)
    assert exact.step == 1
    np.testing.assert_allclose(exact.line, line, atol=1e-6)
    # NaN heights give NaN coordinates
    holes = heights.copy()
    holes[:10] = np.nan
    out = mp.image_coordinates(sensor, grid.crs, grid.transform, window, holes)
    assert np.isnan(out.line[:10]).all() and np.isfinite(out.line[10:]).all()
    assert rows.shape == heights.shape and cols.shape == heights.shape


def test_illumination_angles_from_sun_and_sensor():
    nadir = linescan_sensor(lines=100, samples=100, sun_elevation_deg=30.0)
    line = np.array([50.0])
    xyz = nadir.image_to_ground(line, np.array([50.0]))
    incidence, emission, phase = mp.illumination_angles(nadir, xyz, line)
    assert incidence[0] == pytest.approx(60.0, abs=0.01)
    assert emission[0] == pytest.approx(0.0, abs=0.01)
    assert phase[0] == pytest.approx(60.0, abs=0.02)
    nan = mp.illumination_angles(nadir, xyz, np.array([np.nan]))
    assert all(np.isnan(a[0]) for a in nan)


def test_bilinear_heights():
    rows, cols = np.mgrid[0:6, 0:8].astype(np.float64)
    dem = 2.0 * rows - 3.0 * cols + 1.0
    got = mp.bilinear_heights(dem, np.array([1.25, 4.5, -0.4, 5.6]),
                              np.array([2.5, 6.75, 0.0, 0.0]))
    np.testing.assert_allclose(got[:3], [2 * 1.25 - 7.5 + 1, 9 - 20.25 + 1, 1.0])
    assert np.isnan(got[3])
    holed = dem.copy()
    holed[2, 3] = np.nan
    # on a pixel centre next to a NaN: the pixel itself; between: NaN
    out = mp.bilinear_heights(holed, np.array([2.0, 2.5]), np.array([2.0, 2.5]))
    assert out[0] == dem[2, 2] and np.isnan(out[1])


def test_tile_windows_cover_the_grid_once():
    windows = mp.tile_windows((70, 45), 32)
    cover = np.zeros((70, 45), int)
    for r0, r1, c0, c1 in windows:
        cover[r0:r1, c0:c1] += 1
    assert (cover == 1).all() and len(windows) == 3 * 2


def test_image_window_and_resample_tile():
    image = np.arange(100 * 80, dtype=np.float32).reshape(100, 80)
    line = np.array([[10.5, 20.5], [-1.0, 50.5]])
    sample = np.array([[5.5, 7.5], [3.0, 79.9]])
    span = mp.image_window(line, sample, 100, 80)
    assert span == (8, 53, 3, 80)
    window = image[span[0]:span[1], span[2]:span[3]]
    values = mp.resample_tile(window, (span[0], span[2]), line, sample, 100, 80)
    assert values[0, 0] == image[10, 5] and values[0, 1] == image[20, 7]
    assert np.isnan(values[1, 0])
    assert mp.image_window(np.array([-5.0]), np.array([2.0]), 100, 80) is None
