"""Bodies, PROJ's IAU 2015 codes, and the body behind a CRS (also after a GeoTIFF trip)."""

import numpy as np
import pytest

from demtool import io as dio
from demtool import maps

MOON_R = 1737400.0  # IAU 2015 / PROJ's Moon sphere
MARS_A, MARS_C = 3396190.0, 3376200.0


def test_lookup_by_naif_id_and_codes():
    moon = maps.body_by_naif_id(301)
    assert moon.name == "Moon" and moon.radii == (MOON_R, MOON_R, MOON_R)
    assert moon.radius == MOON_R and moon.is_sphere
    assert moon.iau_code() == "IAU_2015:30100"
    assert moon.iau_code("equirectangular") == "IAU_2015:30110"
    assert moon.iau_code("north_polar") == "IAU_2015:30130"
    assert moon.iau_code("south_polar") == "IAU_2015:30135"
    assert moon.iau_code("ographic") is None  # the Moon's IAU shape is a sphere
    mars = maps.body_by_naif_id(499)
    assert (mars.a, mars.b, mars.c, mars.radius) == (MARS_A, MARS_A, MARS_C, MARS_A)
    assert mars.iau_code("ographic") == "IAU_2015:49901"
    comet = maps.body_by_naif_id(1000012)  # 67P, as in the NavCam study
    assert comet.name == "Churyumov-Gerasimenko"
    assert comet.iau_code() == "IAU_2015:100001200"
    with pytest.raises(KeyError, match="12345"):
        maps.body_by_naif_id(12345)
    with pytest.raises(ValueError, match="unknown IAU CRS kind"):
        moon.iau_code("mercator-ish")


@pytest.mark.parametrize("name, naif", [("Moon", 301), ("MOON", 301), ("mars", 499),
                                        ("D_Moon", 301), ("GCS_Mars_2000_Sphere", 499),
                                        ("67P/CHURYUMOV-GERASIMENKO (1969 R1)", 1000012),
                                        ("Hartley 2", 1000041)])
def test_lookup_by_name(name, naif):
    assert maps.body_by_name(name).naif_id == naif


def test_unknown_name_is_a_key_error():
    with pytest.raises(KeyError, match="Vulcan"):
        maps.body_by_name("Vulcan")


def test_body_from_radii():
    # an ISD gives semi-major and semi-minor radii
    assert maps.body_from_radii(MOON_R, MOON_R, MOON_R).naif_id == 301
    mars = maps.body_from_radii(MARS_A, MARS_A, MARS_C)
    assert mars.naif_id == 499 and mars.radius == MARS_A
    # the model's own radii are kept, the reference sphere is PROJ's
    moon = maps.body_from_radii(1737150.0, name="MOON")
    assert moon.naif_id == 301 and moon.a == 1737150.0 and moon.radius == MOON_R
    unknown = maps.body_from_radii(2000.0, 1500.0, 1000.0, name="Toy")
    assert unknown.naif_id is None and unknown.name == "Toy"
    assert unknown.radius == 2000.0 and unknown.radii == (2000.0, 1500.0, 1000.0)
    with pytest.raises(ValueError, match="positive"):
        maps.body_from_radii(-1.0)


@pytest.mark.parametrize("crs, naif", [
    ("EPSG:4326", 399), ("EPSG:32633", 399), ("IAU_2015:30110", 301),
    ("IAU_2015:49935", 499), ("+proj=longlat +R=1737400 +no_defs", 301),
    ('GEOGCS["GCS_Moon_2000",DATUM["D_Moon_2000",SPHEROID["Moon_2000_IAU_IAG",1737400.0,0.0]],'
     'PRIMEM["Reference_Meridian",0.0],UNIT["Degree",0.0174532925199433]]', 301),
])
def test_body_from_crs(crs, naif):
    assert maps.body_from_crs(crs).naif_id == naif


def test_body_from_crs_keeps_the_crs_reference_surface():
    sphere = maps.body_from_crs("IAU_2015:49900")
    ellipsoid = maps.body_from_crs("IAU_2015:49902")
    assert sphere.naif_id == ellipsoid.naif_id == 499
    assert sphere.c == MARS_A and ellipsoid.c == MARS_C


def test_unknown_body_crs_round_trips_its_name():
    toy = maps.body_from_radii(2500.0, name="Toy")
    found = maps.body_from_crs(toy.geographic_crs())
    assert found.naif_id is None and "Toy" in found.name and found.radius == 2500.0
    assert maps.same_body(found, toy)
    assert not maps.same_body(found, maps.body_from_radii(2600.0, name="Toy"))
    assert "+R=2500" in toy.proj_string()
    oblate = maps.body_from_radii(3000.0, 3000.0, 2000.0, name="Oblate")
    ellipsoid = maps.to_pyproj_crs(oblate.proj_string("ellipsoid")).ellipsoid
    assert (ellipsoid.semi_major_metre, ellipsoid.semi_minor_metre) == (3000.0, 2000.0)
    assert maps.body_from_crs(oblate.proj_string()).radius == 3000.0
    with pytest.raises(ValueError, match="unknown surface"):
        oblate.proj_string("geoid")


def test_same_body():
    moon = maps.body_by_naif_id(301)
    assert maps.same_body(moon, maps.body_from_crs("IAU_2015:30135"))
    assert not maps.same_body(moon, maps.body_by_naif_id(499))
    assert not maps.same_body(moon, maps.body_from_crs("EPSG:4326"))


def test_tags_name_the_body():
    tags = maps.body_by_naif_id(301).tags()
    assert tags == {"body": "Moon", "body_naif_id": 301,
                    "body_radii_m": [MOON_R, MOON_R, MOON_R],
                    "reference_sphere_radius_m": MOON_R, "height_reference": "sphere"}


@pytest.mark.parametrize("make", [
    lambda moon: moon.geographic_crs(),
    lambda moon: "IAU_2015:30135",
    lambda moon: maps.make_projection(moon, "equirectangular", 33.0, 12.0),
    lambda moon: maps.make_projection(moon, "polar-stereographic", 10.0, -84.0),
])
def test_geotiff_round_trip_keeps_body_and_projection(tmp_path, make):
    from affine import Affine

    moon = maps.body_by_naif_id(301)
    crs = maps.to_pyproj_crs(make(moon))
    data = np.arange(12, dtype=np.float32).reshape(3, 4)
    data[0, 0] = np.nan
    path = dio.write_raster(tmp_path / "dem.tif", data, transform=Affine(5, 0, 0, 0, -5, 0),
                            crs=crs, tags=moon.tags())
    raster = dio.read_raster(path)
    back = maps.to_pyproj_crs(raster.crs)
    assert maps.body_from_crs(back).naif_id == 301
    assert raster.tag_json("body_naif_id") == 301
    assert raster.tag_json("reference_sphere_radius_m") == MOON_R
    assert np.isnan(raster.data[0, 0]) and raster.data.dtype == np.float32
    # the same map coordinates from the written and the read CRS
    lon = np.array([30.0, 35.0, 10.0])
    lat = np.array([10.0, 14.0, -85.0]) if not crs.is_geographic else np.array([1.0, 2, 3])
    np.testing.assert_allclose(np.column_stack(maps.lonlat_to_map(back, lon, lat)),
                               np.column_stack(maps.lonlat_to_map(crs, lon, lat)), atol=1e-6)


def test_body_from_crs_asks_proj_once_per_crs(monkeypatch):
    """PROJ's authority search is slow (up to 0.08 s a CRS): a CRS seen before is answered
    from the cache, with the same body; another CRS is identified anew."""
    from pyproj import CRS

    from demtool.maps import bodies

    calls = []
    original = bodies._identify_body

    def counted(crs):
        calls.append(crs.name)
        return original(crs)

    monkeypatch.setattr(bodies, "_identify_body", counted)
    monkeypatch.setattr(bodies, "_BODIES_OF_CRS", {})
    moon = "+proj=eqc +R=1737400 +units=m +no_defs"
    first = bodies.body_from_crs(moon)
    assert bodies.body_from_crs(CRS.from_proj4(moon)) == first and len(calls) == 1
    mars = bodies.body_from_crs("IAU_2015:49900")
    assert len(calls) == 2 and mars.naif_id == 499 and first.naif_id == 301


def test_a_lookup_builds_only_the_body_it_asks_for():
    from demtool.maps import bodies

    bodies._body.cache_clear()
    bodies._BODIES_OF_CRS.clear()
    assert maps.body_by_naif_id(499).name == "Mars"
    assert maps.body_from_radii(1737150.0, name="MOON").naif_id == 301
    assert maps.body_from_crs("IAU_2015:100001230").naif_id == 1000012
    assert bodies._body.cache_info().currsize == 3  # not one per body PROJ knows
    # the whole registry (known_bodies, the radius match) gives the same bodies
    every = {body.naif_id: body for body in maps.known_bodies()}
    assert len(every) > 50 and bodies._body.cache_info().currsize >= len(every)
    for naif in (10, 301, 499, 502, 1000012):
        assert every[naif] == maps.body_by_naif_id(naif)
    assert every[502].name == "Europa" and every[10].name == "Sun"
    # the name index (from PROJ's spheres' names) names each body as its CRS does
    assert all(maps.body_by_name(body.name) == body for body in every.values())


def test_radius_match_equals_a_match_against_every_known_body():
    from math import isclose

    from demtool.maps.bodies import RADIUS_RTOL as rtol

    every = maps.known_bodies()

    def brute_force(a, c):  # a unique match of the sphere's radius or the ellipsoid's a, c
        found = [b for b in every if isclose(b.radius, a, rel_tol=rtol)
                 or (not b.is_sphere and isclose(b.a, a, rel_tol=rtol)
                     and isclose(b.c, c, rel_tol=rtol))]
        return found[0].naif_id if len(found) == 1 else None

    for body in every:
        for a, c in [(body.radius, body.radius), (body.a, body.c),
                     (body.radius * (1 + 5e-7), body.radius), (body.radius * 1.01, body.c)]:
            assert maps.body_from_radii(a, a, c).naif_id == brute_force(a, c), (body, a, c)
