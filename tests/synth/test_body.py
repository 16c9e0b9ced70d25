"""The scene on a spherical body (demtool.synth.body): frames and heights above the sphere."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from demtool.maps import xyz_to_lonlat_height
from demtool.synth import render
from demtool.synth.body import local_heights, placement, surface_height

MOON_R = 1737400.0


def plane_field(a=0.0, b=0.0, c=0.0, n=257, spacing=2.0):
    """h = a x + b y + c on an n × n grid centred on the origin (bilinear is exact)."""
    half = 0.5 * n * spacing
    transform = Affine(spacing, 0.0, -half, 0.0, -spacing, half)
    centers = (np.arange(n) + 0.5) * spacing - half
    x, y = np.meshgrid(centers, -centers)
    return render.height_field(a * x + b * y + c, transform)


def test_frame_round_trip_and_origin():
    place = placement("Moon", 30.0, -45.0)
    assert place.radius == MOON_R
    local = np.array([[0.0, 0.0, 0.0], [100.0, -50.0, 12.0], [0.0, 0.0, 1000.0]])
    xyz = place.to_body(local)
    lon, lat, height = xyz_to_lonlat_height(xyz[[0, 2]], radii=MOON_R)
    np.testing.assert_allclose(lon, 30.0, atol=1e-12)
    np.testing.assert_allclose(lat, -45.0, atol=1e-12)
    np.testing.assert_allclose(height, [0.0, 1000.0], atol=1e-8)  # local Z is radial here
    np.testing.assert_allclose(place.to_local(xyz), local, atol=1e-8)
    # local east is body-fixed east: a point 100 m east has a larger longitude
    lon_e, lat_e, _ = xyz_to_lonlat_height(place.to_body([100.0, 0.0, 0.0]), radii=MOON_R)
    assert lon_e > 30.0 and lat_e == pytest.approx(-45.0, abs=1e-6)
    v = np.array([0.3, -0.4, 0.866])
    np.testing.assert_allclose(place.directions_to_local(place.directions_to_body(v)), v,
                               atol=1e-15)


def test_flat_plane_drops_below_the_sphere_by_the_sagitta():
    place = placement("Moon", 0.0, 0.0)
    field = plane_field()
    # radial line at angle θ from the centre meets the tangent plane at R / cos θ
    theta = np.radians(np.array([0.0, 0.002, 0.005, 0.008]))  # up to 243 m away
    h = surface_height(place, field, np.degrees(theta), 0.0)
    np.testing.assert_allclose(h, MOON_R / np.cos(theta) - MOON_R, atol=1e-7)
    # 256 m from the centre the plane is d²/2R ≈ 1.9 cm above the sphere
    d = 250.0
    h_edge = surface_height(place, field, np.degrees(d / MOON_R), 0.0)
    assert h_edge == pytest.approx(d * d / (2 * MOON_R), rel=1e-3)


@pytest.mark.parametrize("lon0, lat0", [(0.0, 0.0), (-120.0, 60.0), (45.0, -89.0)])
def test_tilted_plane_exact(lon0, lat0):
    a, b, c = 0.3, -0.2, 5.0
    place = placement("Moon", lon0, lat0)
    field = plane_field(a, b, c)
    rng = np.random.default_rng(0)
    local = np.column_stack([rng.uniform(-200, 200, 50), rng.uniform(-200, 200, 50),
                             np.zeros(50)])
    lon, lat, _ = xyz_to_lonlat_height(place.to_body(local), radii=MOON_R)
    h = surface_height(place, field, lon, lat)
    # exact: the radial line s·u from (0, 0, −R) meets z = a x + b y + c at
    # s = (R + c) / (u_z − a u_x − b u_y)
    from demtool.maps import unit_vector

    u = place.directions_to_local(unit_vector(lon, lat))
    s = (MOON_R + c) / (u[:, 2] - a * u[:, 0] - b * u[:, 1])
    np.testing.assert_allclose(h, s - MOON_R, atol=1e-6)
    # and the point at that height lies on the local surface (< 1 µm)
    from demtool.maps import lonlat_height_to_xyz

    p = place.to_local(lonlat_height_to_xyz(lon, lat, h, radii=MOON_R))
    np.testing.assert_allclose(p[:, 2], local_heights(field, p[:, 0], p[:, 1]), atol=1e-6)


def test_outside_the_dem_is_nan_and_bad_placements_fail():
    place = placement("Moon")
    field = plane_field(n=33)
    assert np.isnan(surface_height(place, field, 1.0, 0.0))  # 30 km away
    with pytest.raises(ValueError, match="latitude"):
        placement("Moon", 0.0, 91.0)
    with pytest.raises(ValueError):
        placement("Vulcan")
