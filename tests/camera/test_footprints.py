"""camera --footprints: GeoJSON polygons valid, cut at ±180°, around poles, and the pair's
overlap polygon consistent with camera's overlap."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from shapely.geometry import shape

from demtool.camera.footprints import lonlat_polygons
from demtool.cli import cli
from tests.helpers.camera_isd import nadir_isd, write_isd

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "sensors"
CAMERA = {"focal_mm": 100.0, "pitch_mm": 0.01, "lines": 500, "samples": 500}


def _footprints(tmp_path, isds, *extra):
    paths = [write_isd(tmp_path / f"{name}.json", isd) for name, isd in isds.items()]
    out = tmp_path / "footprints.geojson"
    result = CliRunner().invoke(cli, ["-q", "camera", *map(str, paths), "--footprints",
                                      str(out), "--json", *extra])
    assert result.exit_code == 0, result.output
    return json.loads(out.read_text()), json.loads(result.output)


def _valid(feature):
    geometry = shape(feature["geometry"])
    assert geometry.is_valid, feature["properties"]["name"]
    coords = np.concatenate([np.asarray(p.exterior.coords)
                             for p in getattr(geometry, "geoms", [geometry])])
    assert np.all(np.abs(coords[:, 0]) <= 180.0) and np.all(np.abs(coords[:, 1]) <= 90.0)
    return geometry


def test_a_pair_gives_two_footprints_and_their_overlap(tmp_path):
    # 5 km footprints (100 km up, 500 px of 0.1 mrad), 2 km apart along the parallel
    step = np.degrees(2e3 / (1737400.0 * np.cos(np.radians(5.0))))
    isds = {"a": nadir_isd(10.0, 5.0, 100e3, **CAMERA),
            "b": nadir_isd(10.0 + step, 5.0, 100e3, **CAMERA)}
    collection, report = _footprints(tmp_path, isds)
    assert collection["type"] == "FeatureCollection" and collection["body"]["name"] == "Moon"
    roles = [f["properties"]["role"] for f in collection["features"]]
    assert roles == ["footprint", "footprint", "overlap"]
    a, b, overlap = (_valid(f) for f in collection["features"])
    props = collection["features"][0]["properties"]
    assert props["gsd_m"] == pytest.approx(10.0, rel=0.01) and props["emission_deg"] < 0.1
    assert props["incidence_deg"] == pytest.approx(60.0, abs=0.5)
    assert props["ephemeris_time_tdb_s"] == 0.0
    assert a.geom_type == "Polygon" and a.exterior.is_ccw  # RFC 7946 §3.1.6
    # the overlap polygon is the intersection, with camera's overlap area
    pair = report["pairs"][0]
    ratio = overlap.area / a.intersection(b).area
    assert ratio == pytest.approx(1.0, abs=0.01)
    extra = collection["features"][2]["properties"]
    assert extra["polygon_area_km2"] == pytest.approx(pair["overlap_area_km2"], rel=0.01)
    assert extra["overlap_area_km2"] == pair["overlap_area_km2"]
    assert pair["overlap_fraction_first"] == pytest.approx(0.6, abs=0.02)


def test_a_footprint_across_the_antimeridian_is_cut_in_two(tmp_path):
    collection, _ = _footprints(tmp_path, {"east": nadir_isd(180.0, -20.0, 100e3, **CAMERA)})
    (feature,) = collection["features"]
    geometry = _valid(feature)
    assert feature["geometry"]["type"] == "MultiPolygon" and len(geometry.geoms) == 2
    west, east = sorted(geometry.geoms, key=lambda p: p.centroid.x)
    assert west.bounds[0] == pytest.approx(-180.0) and east.bounds[2] == pytest.approx(180.0)
    width = np.degrees(5e3 / (1737400.0 * np.cos(np.radians(20.0))))
    assert west.bounds[2] - east.bounds[0] + 360.0 == pytest.approx(width, rel=0.05)


def test_a_footprint_around_the_pole_covers_the_cap():
    lon = np.linspace(0.0, 360.0, 64, endpoint=False) + 17.0
    (cap,) = lonlat_polygons(lon, np.full(64, 88.0))
    assert cap.is_valid and cap.bounds == pytest.approx((-180.0, 88.0, 180.0, 90.0))
    assert cap.area == pytest.approx(360.0 * 2.0, rel=1e-9)
    (south,) = lonlat_polygons(lon[::-1], np.full(64, -85.0))  # other orientation
    assert south.is_valid and south.bounds[1] == -90.0 and south.exterior.is_ccw


def test_a_polygon_far_from_the_antimeridian_stays_whole():
    (square,) = lonlat_polygons([-10.0, 10.0, 10.0, -10.0], [0.0, 0.0, 5.0, 5.0])
    assert square.bounds == (-10.0, 0.0, 10.0, 5.0)
    (shifted,) = lonlat_polygons([350.0, 370.0, 370.0, 350.0], [0.0, 0.0, 5.0, 5.0])
    assert shifted.bounds == (-10.0, 0.0, 10.0, 5.0)  # 0-360 longitudes come to ±180


@pytest.mark.slow
@pytest.mark.data
@pytest.mark.skipif(not (DATA / "apollo15_cubes").is_dir(),
                    reason="../shared/data/sensors is absent")
def test_apollo15_cube_pair_footprints_are_valid_and_overlap_as_camera_says(tmp_path):
    paths = sorted((DATA / "apollo15_cubes").glob("*.cub"))
    out = tmp_path / "apollo.geojson"
    result = CliRunner().invoke(cli, ["-q", "camera", *map(str, paths), "--footprints",
                                      str(out), "--json"])
    assert result.exit_code == 0, result.output
    collection, report = json.loads(out.read_text()), json.loads(result.output)
    footprints = [f for f in collection["features"] if f["properties"]["role"] == "footprint"]
    (overlap,) = [f for f in collection["features"] if f["properties"]["role"] == "overlap"]
    first, second = (_valid(f) for f in footprints)
    common = _valid(overlap)
    pair = report["pairs"][0]
    assert overlap["properties"]["polygon_area_km2"] == pytest.approx(
        pair["overlap_area_km2"], rel=0.01)
    assert common.area / first.intersection(second).area == pytest.approx(1.0, abs=0.01)
