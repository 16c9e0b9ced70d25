"""One longitude rule (issue 31, class 6) in ``camera``, ``mapproject`` and the sensor
``dem`` route: a stereo scene centred on the antimeridian gives what the same scene at
10 °E gives, and ground named in −180…180, in 0…360 or by a box across 180° is one
ground.  (``compare``'s share of the rule: tests/cli/test_compare_planetary.py.)"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from demtool.cli import cli
from demtool.mapproject.params import bounds_problem
from demtool.maps import MapGrid, longitude_span, to_pyproj_crs
from tests.helpers.frame_scene import height_on_grid, make_frame_scene, write_frame_scene


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The same 160 px frame pair at 180 °E (its footprint across the antimeridian) and
    at 10 °E."""
    out = {}
    for lon in (180.0, 10.0):
        scene = make_frame_scene(size=160, seed=7, lon0=lon)
        out[lon] = scene, write_frame_scene(scene, tmp_path_factory.mktemp(f"lon{lon:g}"))
    return out


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_longitude_span_reads_a_box_across_the_antimeridian():
    assert longitude_span(179.9, -179.9) == pytest.approx((179.9, 180.1))
    assert longitude_span(-10.0, 20.0) == (-10.0, 20.0)
    assert bounds_problem((179.98, 4.98, -179.98, 5.02)) is None
    assert "MIN < MAX" in bounds_problem((10.0, 4.0, 10.0, 5.0))
    assert "at most 180° wide" in bounds_problem((11.0, 4.0, 10.0, 5.0))  # swapped
    assert bounds_problem((359.9, 4.0, 0.1, 5.0)) is None  # across 0°E in 0…360


def test_camera_pair_on_the_antimeridian_is_the_pair_at_10_east(scenes):
    reports = {}
    for lon, (_, paths) in scenes.items():
        result = invoke("-q", "camera", paths["left_isd"], paths["right_isd"], "--json")
        assert result.exit_code == 0, result.output
        reports[lon] = json.loads(result.output)
    at_180, at_10 = reports[180.0], reports[10.0]
    for key in ("overlap_area_km2", "base_to_height", "convergence_deg"):
        assert at_180["pairs"][0][key] == pytest.approx(at_10["pairs"][0][key], rel=1e-6)
    for one, other in zip(at_180["cameras"], at_10["cameras"], strict=True):
        assert abs(abs(one["center_lon_deg"]) - 180.0) < 1e-6
        assert one["gsd_m"] == pytest.approx(other["gsd_m"], rel=1e-6)
        assert 0.0 <= one["sun_azimuth_deg"] < 360.0


def test_mapproject_bounds_in_either_convention_and_across_180_are_one_grid(scenes,
                                                                           tmp_path):
    _, paths = scenes[180.0]
    arrays, crss = [], []
    for name, bounds in (("east", (179.98, 4.98, 180.02, 5.02)),
                         ("west", (-180.02, 4.98, -179.98, 5.02)),
                         ("across", (179.98, 4.98, -179.98, 5.02))):
        out = tmp_path / f"{name}.tif"
        result = invoke("mapproject", paths["left"], "--sensor", paths["left_isd"],
                        "--height", 0, "--gsd", 5, "--bounds", *bounds, "--out", out)
        assert result.exit_code == 0, result.output
        with rasterio.open(out) as dataset:
            arrays.append(dataset.read(1))
            crss.append(dataset.crs)
            assert dataset.width == pytest.approx(0.04 * np.pi / 180 * 1737400
                                                  * np.cos(np.radians(5)) / 5, abs=3)
    assert crss[0] == crss[1] == crss[2]
    assert np.isfinite(arrays[0]).mean() > 0.3
    for other in arrays[1:]:
        np.testing.assert_array_equal(arrays[0], other)


def test_sensor_dem_on_the_antimeridian_is_as_good_as_at_10_east(scenes, tmp_path):
    """rectify → sgm → dem on both scenes: the same completeness and error to truth."""
    scores = {}
    for lon, (scene, paths) in scenes.items():
        work = tmp_path / f"lon{lon:g}"
        steps = [("rectify", paths["left"], paths["right"], "--sensor-left", paths["left_isd"],
                  "--sensor-right", paths["right_isd"], "--out", work / "rect"),
                 ("sgm", work / "rect" / "left_rect.tif", work / "rect" / "right_rect.tif",
                  "--rectify", work / "rect" / "rectify.npz", "--out", work / "d.tif"),
                 ("dem", "--disparity", work / "d.tif", "--rectify",
                  work / "rect" / "rectify.npz", "--out", work / "dem.tif")]
        for step in steps:
            result = invoke("-q", *step)
            assert result.exit_code == 0, result.output
        with rasterio.open(work / "dem.tif") as dataset:
            dem = dataset.read(1)
            grid = MapGrid(to_pyproj_crs(dataset.crs), dataset.transform, dataset.width,
                           dataset.height)
        error = (dem - height_on_grid(scene, grid))[np.isfinite(dem)]
        scores[lon] = (np.isfinite(dem).mean(), float(np.sqrt(np.mean(error ** 2))))
    assert scores[180.0][0] == pytest.approx(scores[10.0][0], abs=0.005)
    assert scores[180.0][1] == pytest.approx(scores[10.0][1], rel=0.02)
    assert scores[180.0][1] < 0.6 * 5.0  # GSD 5 m
