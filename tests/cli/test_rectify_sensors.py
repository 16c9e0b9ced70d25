"""Calibrated frame stereo end to end: rectify --sensor-left/--sensor-right → sgm → dem
on the body's map, against the synthetic scene's exact truth; and its bad inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.dem.sensors import overlap_mask
from demtool.maps import body_from_crs, to_pyproj_crs
from demtool.maps.grids import MapGrid
from demtool.sensors.arrays import rotate_pointing, rotation_vector_matrix
from tests.helpers.frame_scene import frame_isd, make_frame_scene, write_frame_scene


@pytest.fixture(scope="module")
def frame_scene(tmp_path_factory):
    scene = make_frame_scene(size=160, seed=7)
    folder = tmp_path_factory.mktemp("frame_scene")
    return scene, write_frame_scene(scene, folder)


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _rectify(paths, out, right_isd=None, *extra):
    return _invoke("rectify", paths["left"], paths["right"], "--sensor-left",
                   paths["left_isd"], "--sensor-right", right_isd or paths["right_isd"],
                   "--out", out, *extra)


def _truth_on(dem_path, scene):
    with rasterio.open(dem_path) as ds:
        dem = ds.read(1)
        grid = MapGrid(to_pyproj_crs(ds.crs), ds.transform, ds.width, ds.height)
        tags = ds.tags()
    from tests.helpers.frame_scene import height_on_grid

    return dem, height_on_grid(scene, grid), grid, tags


def _check_point_cloud(path, dem, grid, gsd):
    """The LAZ of --points-out: the DEM's CRS, the points the DEM was gridded from."""
    import laspy

    las = laspy.read(path)
    assert las.header.parse_crs().equals(grid.crs)
    assert {"ray_gap", "brightness"} <= set(las.point_format.extra_dimension_names)
    inverse = ~grid.transform
    x, y = np.asarray(las.x), np.asarray(las.y)
    cols = inverse.a * x + inverse.b * y + inverse.c
    rows = inverse.d * x + inverse.e * y + inverse.f
    cells = dem[rows.astype(int), cols.astype(int)]
    assert len(las.points) > 0.5 * np.isfinite(dem).sum()
    assert np.nanmedian(np.abs(np.asarray(las.z) - cells)) < 0.3 * gsd
    assert np.median(las.ray_gap) < 0.05 * gsd and las.intensity.max() > 0


@pytest.mark.slow
def test_calibrated_frame_stereo_matches_truth(frame_scene, tmp_path):
    scene, paths = frame_scene
    rect = tmp_path / "rect"
    run = _rectify(paths, rect)
    assert run.exit_code == 0, run.output
    assert "pointing correction of the right camera: none needed" in run.output
    data = dio.read_npz(rect / "rectify.npz", "rectification")
    assert bool(data["calibrated"]) and int(data["format_version"]) == dio.NPZ_FORMAT_VERSION
    summary = json.loads((rect / "rectify.npz.json").read_text())["summary"]
    assert summary["rms_vertical_residual_px"] < 0.4 and not summary["pointing_corrected"]
    disparity = tmp_path / "disparity.tif"
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--out", disparity)
    assert run.exit_code == 0, run.output
    dem_path, error_path, mask_path = (tmp_path / n for n in ("dem.tif", "err.tif",
                                                              "mask.tif"))
    run = _invoke("dem", "--disparity", disparity, "--rectify", rect / "rectify.npz",
                  "--error-out", error_path, "--interpolated-mask", mask_path,
                  "--points-out", tmp_path / "points.laz", "--out", dem_path)
    assert run.exit_code == 0, run.output
    dem, truth, grid, tags = _truth_on(dem_path, scene)
    _check_point_cloud(tmp_path / "points.laz", dem, grid, scene.gsd_m)
    gsd = scene.gsd_m
    assert grid.gsd[0] == pytest.approx(gsd, rel=0.05)  # auto GSD from the images
    assert body_from_crs(grid.crs).name == "Moon" and tags["body"] == "Moon"
    assert "IAU" in grid.crs.to_wkt() or "Moon" in grid.crs.name
    # completeness over the stereo overlap at the true heights
    overlap = overlap_mask(grid, scene.left, scene.right, float(np.nanmedian(truth)))
    assert np.isfinite(dem[overlap]).mean() >= 0.98
    error = (dem - truth)[np.isfinite(dem)]
    rmse, mean = float(np.sqrt(np.mean(error ** 2))), float(np.mean(error))
    assert rmse < 0.6 * gsd, (rmse, mean)
    assert abs(mean) < 0.2 * gsd
    gaps = dio.read_raster(error_path).data
    assert np.nanmedian(gaps) < 0.05 * gsd  # exact models: rays meet
    filled = dio.read_raster(mask_path).data
    assert set(np.unique(filled[np.isfinite(filled)])) <= {0.0, 1.0}
    sidecar = json.loads((tmp_path / "dem.tif.json").read_text())["summary"]
    assert sidecar["route"] == "disparity-sensors" and sidecar["behind_camera"] == 0


@pytest.mark.slow
def test_pointing_correction_is_fitted_and_stored(frame_scene, tmp_path):
    scene, paths = frame_scene
    turn = rotation_vector_matrix([0.0, 2.0e-3, 0.0])  # ≈ about the east (baseline) axis
    wrong = rotate_pointing(scene.right, turn)
    isd = tmp_path / "right_off.json"
    isd.write_text(json.dumps(frame_isd(wrong)))
    rect = tmp_path / "rect"
    run = _rectify(paths, rect, isd)
    assert run.exit_code == 0, run.output
    assert "pointing correction of the right camera" in run.output
    summary = json.loads((rect / "rectify.npz.json").read_text())["summary"]
    assert summary["pointing_corrected"]
    assert 1.5 < summary["pointing_correction_angle_mrad"] < 2.5
    assert summary["rms_vertical_residual_before_px"] > 3.0
    assert summary["rms_vertical_residual_px"] < 0.4
    data = dio.read_npz(rect / "rectify.npz", "rectification")
    # the stored right model is the corrected one: its rays agree with the true camera's
    from demtool.dem.inputs import models_from_rectification

    _, right = models_from_rectification(data, rect / "rectify.npz")
    lines, samples = np.array([20.0, 80.0, 140.0]), np.array([30.0, 90.0, 150.0])
    true = scene.right.image_to_ray(lines, samples).direction
    stored = right.image_to_ray(lines, samples).direction
    angle = np.arccos(np.clip(np.sum(true * stored, axis=1), -1, 1))
    assert angle.max() < 0.3e-3  # radians; 2 mrad before


def test_bad_inputs_one_line_exit_1_no_output(frame_scene, tmp_path):
    scene, paths = frame_scene
    out = tmp_path / "out"
    # a model whose image size disagrees with the image
    small = make_frame_scene(size=64, seed=1)
    isd = tmp_path / "small.json"
    isd.write_text(json.dumps(frame_isd(small.right)))
    run = _rectify(paths, out, isd)
    assert run.exit_code == 1 and "small.json: the model is for a 64 x 64 px image" in run.output
    # a line-scan model
    from pathlib import Path

    linescan = Path(__file__).parents[1] / "sensors" / "data" / "orbitalLineScan.json"
    run = _rectify(paths, out, linescan)
    assert run.exit_code == 1 and "is a line-scan model" in run.output
    assert "mapproject" in run.output
    # models of different bodies
    mars = frame_isd(scene.right)
    # (radii 0.1 % larger: another body, with the camera still above it; Mars' radii put
    # it inside, which the reader refuses first, naming instrument_position)
    mars["radii"] = {"semimajor": 1739137.4, "semiminor": 1739137.4, "unit": "m"}
    isd = tmp_path / "mars.json"
    isd.write_text(json.dumps(mars))
    run = _rectify(paths, out, isd)
    assert run.exit_code == 1 and "mars.json: the model is on another body" in run.output
    for result in [run]:
        assert result.output.count("Error:") == 1
    assert not out.exists() or not any(out.iterdir())
    # only one model: a usage error
    run = _invoke("rectify", paths["left"], paths["right"], "--sensor-left",
                  paths["left_isd"], "--out", out)
    assert run.exit_code == 2 and "--sensor-right" in run.output


def test_dem_refuses_bad_calibrated_files(frame_scene, tmp_path):
    scene, paths = frame_scene
    rect = tmp_path / "rect"
    assert _rectify(paths, rect).exit_code == 0
    data = dio.read_npz(rect / "rectify.npz", "rectification")
    width, height = data["size_rect"]
    disparity = tmp_path / "d.tif"
    dio.write_raster(disparity, np.zeros((height, width), np.float32))
    broken = {k: v for k, v in data.items() if k not in ("kind", "format_version",
                                                        "sensor_right_rotation")}
    dio.write_npz(tmp_path / "broken.npz", "rectification", broken)
    out = tmp_path / "dem.tif"
    run = _invoke("dem", "--disparity", disparity, "--rectify", tmp_path / "broken.npz",
                  "--out", out)
    assert run.exit_code == 1 and "lacks the key 'sensor_right_rotation'" in run.output
    no_k = {k: v for k, v in data.items() if k != "K_left_rect"}
    np.savez(tmp_path / "nok.npz", **no_k)
    run = _invoke("dem", "--disparity", disparity, "--rectify", tmp_path / "nok.npz",
                  "--out", out)
    assert run.exit_code == 1
    assert "nok.npz: calibrated rectification file lacks the key 'K_left_rect'" in run.output
    run = _invoke("dem", "--disparity", disparity, "--rectify", rect / "rectify.npz",
                  "--cameras", paths["left_isd"], "--out", out)
    assert run.exit_code == 1 and "is calibrated" in run.output
    assert not out.exists()


def test_a_pair_1800_km_apart_is_not_blamed_on_the_spice(frame_scene, tmp_path):
    """Issue 31, class 7: the right camera turned 60° about the pole (≈1 800 km away): the
    footprints are compared before any matching, and the message says so."""
    import copy

    scene, paths = frame_scene
    far = copy.copy(scene.right)
    turn = np.radians(60.0)
    spin = np.array([[np.cos(turn), -np.sin(turn), 0.0], [np.sin(turn), np.cos(turn), 0.0],
                     [0.0, 0.0, 1.0]])
    far.position = spin @ scene.right.position
    far.rotation = spin @ scene.right.rotation
    isd = tmp_path / "far.json"
    isd.write_text(json.dumps(frame_isd(far)))
    out = tmp_path / "out"
    run = _rectify(paths, out, isd)
    errors = [line for line in run.output.splitlines() if line.startswith("Error:")]
    assert run.exit_code == 1 and len(errors) == 1, run.output
    assert "far.json: its footprint" in errors[0] and "does not overlap" in errors[0]
    assert "SPICE" not in run.output
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
def test_dem_blames_a_nan_model_in_rectify_npz_not_the_disparity(frame_scene, tmp_path):
    scene, paths = frame_scene
    rect = tmp_path / "rect"
    assert _rectify(paths, rect).exit_code == 0
    data = dio.read_npz(rect / "rectify.npz", "rectification")
    width, height = (int(v) for v in data["size_rect"])
    disparity = tmp_path / "d.tif"
    dio.write_raster(disparity, np.zeros((height, width), np.float32))
    broken = {k: v for k, v in data.items() if k not in ("kind", "format_version")}
    broken["sensor_right_position"] = np.full(3, np.nan)
    dio.write_npz(tmp_path / "nan.npz", "rectification", broken)
    out = tmp_path / "dem.tif"
    run = _invoke("dem", "--disparity", disparity, "--rectify", tmp_path / "nan.npz",
                  "--out", out)
    errors = [line for line in run.output.splitlines() if line.startswith("Error:")]
    assert run.exit_code == 1 and len(errors) == 1, run.output
    assert f"{tmp_path / 'nan.npz'}: key 'sensor_right_position'" in errors[0]
    assert "non-finite" in errors[0] and not out.exists()
