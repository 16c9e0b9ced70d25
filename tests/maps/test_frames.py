"""Planetocentric lon/lat/height <-> body-fixed XYZ and east-north-up frames."""

import numpy as np
import pytest

from demtool import maps

R = 1737400.0


@pytest.mark.parametrize("lon, lat, h, xyz", [
    (0.0, 0.0, 0.0, (R, 0, 0)),
    (90.0, 0.0, 100.0, (0, R + 100, 0)),
    (180.0, 0.0, -50.0, (-(R - 50), 0, 0)),
    (-90.0, 0.0, 0.0, (0, -R, 0)),
    (123.0, 90.0, 10.0, (0, 0, R + 10)),
    (45.0, 45.0, 0.0, (R / 2, R / 2, R / np.sqrt(2))),
])
def test_known_points(lon, lat, h, xyz):
    np.testing.assert_allclose(maps.lonlat_height_to_xyz(lon, lat, h, radii=R), xyz,
                               atol=1e-6)


def test_round_trip_is_exact():
    rng = np.random.default_rng(1)
    lon = rng.uniform(-180, 180, 1000)
    lat = rng.uniform(-89.9, 89.9, 1000)
    h = rng.uniform(-9000, 11000, 1000)
    xyz = maps.lonlat_height_to_xyz(lon, lat, h, radii=R)
    assert xyz.shape == (1000, 3)
    back_lon, back_lat, back_h = maps.xyz_to_lonlat_height(xyz, radii=R)
    np.testing.assert_allclose(maps.wrap_longitude(back_lon - lon), 0, atol=1e-9)
    np.testing.assert_allclose(back_lat, lat, atol=1e-9)
    np.testing.assert_allclose(back_h, h, atol=1e-6)
    np.testing.assert_allclose(maps.height_above_sphere(xyz, R), h, atol=1e-6)


def test_triaxial_local_radius_and_radial_height():
    radii = (3000.0, 2000.0, 1000.0)
    axes = maps.lonlat_height_to_xyz([0, 90, 0], [0, 0, 90], 0.0, radii=radii)
    np.testing.assert_allclose(axes, [[3000, 0, 0], [0, 2000, 0], [0, 0, 1000]], atol=1e-9)
    # a point 5 m above the ellipsoid along the radius at (30°E, 40°N)
    p = maps.lonlat_height_to_xyz(30.0, 40.0, 5.0, radii=radii)
    u = p / np.linalg.norm(p)
    surface = p - 5.0 * u
    assert np.sum((surface / radii) ** 2) == pytest.approx(1.0, abs=1e-12)
    lon, lat, h = maps.xyz_to_lonlat_height(p, radii=radii)
    assert (lon, lat, h) == pytest.approx((30.0, 40.0, 5.0), abs=1e-9)


def test_enu_frames_are_the_local_derivatives():
    rng = np.random.default_rng(2)
    lon = rng.uniform(-180, 180, 50)
    lat = rng.uniform(-85, 85, 50)
    frames = maps.enu_frame(lon, lat)
    assert frames.shape == (50, 3, 3)
    np.testing.assert_allclose(frames @ frames.swapaxes(1, 2), np.broadcast_to(np.eye(3),
                               (50, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-12)  # right-handed
    eps = 1e-6
    d_lon = maps.unit_vector(lon + eps, lat) - maps.unit_vector(lon - eps, lat)
    d_lat = maps.unit_vector(lon, lat + eps) - maps.unit_vector(lon, lat - eps)
    east = d_lon / np.linalg.norm(d_lon, axis=1, keepdims=True)
    north = d_lat / np.linalg.norm(d_lat, axis=1, keepdims=True)
    np.testing.assert_allclose(frames[:, 0], east, atol=1e-7)
    np.testing.assert_allclose(frames[:, 1], north, atol=1e-7)
    np.testing.assert_allclose(frames[:, 2], maps.unit_vector(lon, lat), atol=1e-12)
    # at (0°, 0°): east = +Y, north = +Z, up = +X
    np.testing.assert_allclose(maps.enu_frame(0.0, 0.0), [[0, 1, 0], [0, 0, 1], [1, 0, 0]],
                               atol=1e-15)


def test_wrap_longitude():
    np.testing.assert_allclose(maps.wrap_longitude([190.0, -190.0, 360.0, 179.0]),
                               [-170.0, 170.0, 0.0, 179.0])
    np.testing.assert_allclose(maps.wrap_longitude([10.0, 350.0], center=180.0), [10, 350])
