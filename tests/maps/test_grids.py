"""Map grids: snapping, footprints, cell centres on the sphere, degree grids in metres."""

import math

import numpy as np
import pytest
from affine import Affine

from demtool import maps


@pytest.fixture(scope="module")
def moon():
    return maps.body_by_naif_id(301)


def test_snap_grid_is_pixel_aligned_and_covers_the_box(moon):
    crs = maps.make_projection(moon, "equirectangular", 0.0, 0.0)
    grid = maps.snap_grid(crs, -123.0, 40.0, 377.0, 260.0, 50.0)
    assert grid.transform == Affine(50.0, 0.0, -150.0, 0.0, -50.0, 300.0)
    assert grid.shape == (6, 11)
    xmin, ymin, xmax, ymax = grid.bounds()
    assert xmin <= -123 and ymin <= 40 and xmax >= 377 and ymax >= 260
    assert (xmax - xmin) - (377 + 123) < 2 * 50 and (ymax - ymin) - 220 < 2 * 50
    # a box on the lattice is kept as it is
    same = maps.snap_grid(crs, -150.0, 0.0, 400.0, 300.0, 50.0)
    assert same.shape == (6, 11) and same.transform.c == -150.0
    with pytest.raises(ValueError, match="gsd"):
        maps.snap_grid(crs, 0, 0, 1, 1, 0.0)


@pytest.mark.parametrize("center", [(20.0, 10.0), (179.9, -30.0), (60.0, -85.0)])
def test_grid_from_footprint_covers_it(moon, center):
    lon0, lat0 = center
    lon = lon0 + np.array([-0.3, 0.3, 0.3, -0.3])
    lat = lat0 + np.array([-0.2, -0.2, 0.2, 0.2])
    grid = maps.grid_from_lonlat(moon, lon, lat, 20.0)
    xmin, ymin, xmax, ymax = grid.bounds()
    # every point of the polygon's edges (densely sampled) lies inside
    t = np.linspace(0, 1, 200)
    edges_lon = np.concatenate([a + t * (b - a)
                                for a, b in zip(lon, np.roll(lon, -1), strict=True)])
    edges_lat = np.concatenate([a + t * (b - a)
                                for a, b in zip(lat, np.roll(lat, -1), strict=True)])
    x, y = maps.lonlat_to_map(grid.crs, edges_lon, edges_lat)
    assert (x >= xmin).all() and (x <= xmax).all() and (y >= ymin).all() and (y <= ymax).all()
    assert xmin % 20.0 == 0 and ymax % 20.0 == 0 and grid.gsd == (20.0, 20.0)
    assert x.max() - x.min() > (grid.width - 2) * 20.0  # tight: at most a pixel each side
    # the same grid from body-fixed ground points of the polygon
    xyz = maps.lonlat_height_to_xyz(edges_lon, edges_lat, 500.0, radii=moon.radius)
    from_points = maps.grid_from_xyz(moon, xyz, 20.0)
    assert from_points.shape == grid.shape and from_points.transform == grid.transform


def test_grid_xyz_and_lonlat_of_cell_centres(moon):
    crs = maps.make_projection(moon, "equirectangular", 45.0, 30.0)
    grid = maps.snap_grid(crs, 0.0, 1e6, 1000.0, 1e6 + 600.0, 100.0)
    heights = np.arange(60, dtype=np.float64).reshape(6, 10) * 10.0 - 250.0
    heights[2, 3] = np.nan
    xyz = maps.grid_xyz(grid, heights)
    assert xyz.shape == (6, 10, 3)
    np.testing.assert_allclose(maps.height_above_sphere(xyz, moon.radius), heights, atol=1e-6)
    assert np.isnan(xyz[2, 3]).all()
    lon, lat = maps.grid_lonlat(grid)
    # cell (0, 0) centre at x = 50, y = 1e6 + 550: invert the closed form of eqc
    R = moon.radius
    assert lon[0, 0] == pytest.approx(45.0 + math.degrees(50.0 / (R * math.cos(math.radians(30)))))
    assert lat[0, 0] == pytest.approx(math.degrees((1e6 + 550.0) / R))
    unit = maps.unit_vector(lon, lat)
    np.testing.assert_allclose(xyz[0, 0] / np.linalg.norm(xyz[0, 0]), unit[0, 0], atol=1e-12)
    with pytest.raises(ValueError, match="heights have shape"):
        maps.grid_xyz(grid, np.zeros((3, 3)))


def test_degree_grid_in_metres(moon):
    transform = Affine(0.01, 0.0, 10.0, 0.0, -0.01, 61.0)  # 0.01° pixels, 60…61°N
    sx, sy = maps.degree_pixel_size(transform, 60.0, moon.radius)
    per_degree = moon.radius * math.pi / 180
    assert sy == pytest.approx(0.01 * per_degree)  # ≈ 303.2 m
    assert sx == pytest.approx(0.5 * 0.01 * per_degree)  # cos 60° = 0.5
    grid = maps.metric_grid_for("IAU_2015:30100", transform, (100, 200))
    assert grid.crs.coordinate_operation.method_name.startswith("Equidistant Cylindrical")
    assert maps.body_from_crs(grid.crs).naif_id == 301
    gsd = grid.gsd[0]
    # the degree pixel's ground size at the centre (60.5°N), geometric mean
    expected = math.sqrt(per_degree * 0.01 * math.cos(math.radians(60.5)) * per_degree * 0.01)
    assert gsd == pytest.approx(expected, rel=2e-3)
    # covers the 2° x 1° footprint: about 1 degree of latitude of rows
    assert grid.height * gsd == pytest.approx(per_degree, rel=0.02)
    polar = maps.metric_grid_for("IAU_2015:30100", Affine(0.1, 0, 0, 0, -0.1, -80.0),
                                 (50, 100))
    assert polar.crs.coordinate_operation.method_name.startswith("Polar Stereographic")
    with pytest.raises(ValueError, match="not geographic"):
        maps.metric_grid_for("IAU_2015:30110", transform, (10, 10))
