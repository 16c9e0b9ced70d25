"""Projections on the body's sphere checked against Snyder's closed forms."""

import numpy as np
import pytest

from demtool import maps


@pytest.fixture(scope="module")
def moon():
    return maps.body_by_naif_id(301)


def test_equirectangular_matches_the_closed_form(moon):
    # Snyder (1987), Map Projections — A Working Manual, eqs. 12-1, 12-2:
    # x = R (λ − λ0) cos φ1, y = R φ (latitude of origin 0)
    crs = maps.make_projection(moon, "equirectangular", 100.0, 20.0)
    lon = np.array([95.0, 100.0, 107.5])
    lat = np.array([15.0, 20.0, 26.0])
    x, y = maps.lonlat_to_map(crs, lon, lat)
    R = moon.radius
    np.testing.assert_allclose(x, R * np.radians(lon - 100.0) * np.cos(np.radians(20.0)),
                               atol=1e-6)
    np.testing.assert_allclose(y, R * np.radians(lat), atol=1e-6)
    back_lon, back_lat = maps.map_to_lonlat(crs, x, y)
    np.testing.assert_allclose(back_lon, lon, atol=1e-10)
    np.testing.assert_allclose(back_lat, lat, atol=1e-10)


@pytest.mark.parametrize("lat_ts", [80.0, -80.0, -88.5])
def test_polar_stereographic_matches_the_closed_form_and_is_true_at_lat_ts(moon, lat_ts):
    # Snyder (1987) eqs. 21-5 (k0 from the standard parallel) and 21-1…21-4 on the sphere:
    # ρ = 2 R k0 tan(π/4 − |φ|/2), x = ρ sin λ, y = ∓ρ cos λ (north / south)
    crs = maps.make_projection(moon, "polar-stereographic", 40.0, lat_ts)
    sign = np.sign(lat_ts)
    lon = np.array([0.0, 40.0, -120.0, 175.0])
    lat = sign * np.array([89.0, 80.0, 75.0, 85.0])
    x, y = maps.lonlat_to_map(crs, lon, lat)
    k0 = (1 + np.sin(np.radians(abs(lat_ts)))) / 2
    rho = 2 * moon.radius * k0 * np.tan(np.pi / 4 - np.radians(np.abs(lat)) / 2)
    np.testing.assert_allclose(x, rho * np.sin(np.radians(lon)), atol=1e-6)
    np.testing.assert_allclose(y, -sign * rho * np.cos(np.radians(lon)), atol=1e-6)
    # map distance equals ground distance along the parallel lat_ts
    d = 1e-4
    x0, y0 = maps.lonlat_to_map(crs, 40.0, lat_ts)
    x1, y1 = maps.lonlat_to_map(crs, 40.0 + d, lat_ts)
    ground = moon.radius * np.cos(np.radians(lat_ts)) * np.radians(d)
    assert np.hypot(x1 - x0, y1 - y0) == pytest.approx(ground, rel=1e-6)


@pytest.mark.parametrize("center_lat, method", [(69.0, "Equidistant Cylindrical"),
                                                (71.0, "Polar Stereographic"),
                                                (-75.0, "Polar Stereographic"),
                                                (0.0, "Equidistant Cylindrical")])
def test_auto_switches_at_70_degrees(moon, center_lat, method):
    crs = maps.choose_projection(moon, [10.0, 12.0], [center_lat - 0.5, center_lat + 0.5])
    assert crs.coordinate_operation.method_name.startswith(method)
    assert maps.body_from_crs(crs).naif_id == 301


def test_footprint_center_across_the_antimeridian_and_pole():
    lon, lat = maps.footprint_center([179.0, -179.0, -179.0, 179.0], [-1.0, -1.0, 1.0, 1.0])
    assert abs(maps.wrap_longitude(lon - 180.0)) < 1e-9 and abs(lat) < 1e-9
    _, lat = maps.footprint_center([0.0, 90.0, 180.0, 270.0], [85.0] * 4)
    assert lat == pytest.approx(90.0)
    with pytest.raises(ValueError, match="no finite point"):
        maps.footprint_center([np.nan], [0.0])


def test_map_xyz_round_trip(moon):
    crs = maps.make_projection(moon, "auto", -30.0, 5.0)
    rng = np.random.default_rng(3)
    x = rng.uniform(-5e4, 5e4, (20, 30))
    y = rng.uniform(1e5, 2e5, (20, 30))
    h = rng.uniform(-3000, 3000, (20, 30))
    xyz = maps.map_to_xyz(crs, x, y, h)
    assert xyz.shape == (20, 30, 3)
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=-1) - moon.radius, h, atol=1e-6)
    bx, by, bh = maps.xyz_to_map(crs, xyz)
    np.testing.assert_allclose(bx, x, atol=1e-6)
    np.testing.assert_allclose(by, y, atol=1e-6)
    np.testing.assert_allclose(bh, h, atol=1e-6)


def test_bad_projection_and_non_sphere_crs(moon):
    with pytest.raises(ValueError, match="unknown projection 'mercator'"):
        maps.make_projection(moon, "mercator", 0.0, 0.0)
    with pytest.raises(ValueError, match="on an ellipsoid"):
        maps.crs_radius("IAU_2015:49902")
    assert maps.crs_radius("IAU_2015:49910") == 3396190.0


def test_map_on_an_ellipsoid_is_geodetic_as_proj():
    """A CRS on an ellipsoid (UTM on WGS 84): geodetic latitude, height along the normal,
    as PROJ's geographic 3D -> geocentric conversion."""
    from pyproj import Transformer

    x, y = np.array([359746.0, 360100.0]), np.array([7651923.0, 7651500.0])
    h = np.array([2300.0, -40.0])
    xyz = maps.map_to_xyz("EPSG:32740", x, y, h)
    lon, lat = Transformer.from_crs("EPSG:32740", "EPSG:4326", always_xy=True).transform(x, y)
    want = np.column_stack(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
                           .transform(lon, lat, h))
    np.testing.assert_allclose(xyz, want, atol=1e-6)
    bx, by, bh = maps.xyz_to_map("EPSG:32740", xyz)
    np.testing.assert_allclose(np.column_stack([bx, by, bh]), np.column_stack([x, y, h]),
                               atol=1e-6)
