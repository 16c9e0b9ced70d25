"""`demtool synth` through the command line: files, tags, round trips, errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from scipy.ndimage import map_coordinates

from demtool import io
from demtool.cli import cli
from demtool.sensors.pinhole import cameras_from_arrays
from demtool.synth.folder import load_scene

SCENE_FILES = ["view_00.tif", "view_01.tif", "view_02.tif", "view_03.tif", "truth_dem.tif",
               "truth_dem_target.tif", "albedo.tif", "cameras.npz", "scene.json",
               "scene.json.json"]
TINY_ARGS = ["--size", "96", "--views", "3", "--image-size", "64", "--craters", "8",
             "--crater-max", "20", "--boulders", "20"]


def test_writes_every_file_of_the_contract(small_scene_dir):
    assert sorted(p.name for p in small_scene_dir.iterdir()) == sorted(SCENE_FILES)


@pytest.mark.parametrize("name", ["view_00.tif", "view_02.tif", "truth_dem.tif",
                                  "truth_dem_target.tif", "albedo.tif"])
def test_rasters_are_float32_with_nan_nodata_and_provenance_tags(small_scene_dir, name):
    with rasterio.open(small_scene_dir / name) as dataset:
        assert dataset.dtypes == ("float32",)
        assert np.isnan(dataset.nodata)
        assert dataset.crs is None
        tags = dataset.tags()
    assert tags["demtool_stage"] == "synth"
    assert json.loads(tags["demtool_params"])["size"] == 256
    expected_frame = "map:local" if name in ("truth_dem.tif", "albedo.tif") else (
        "image:view_00" if name != "view_02.tif" else "image:view_02")
    assert tags["frame"] == expected_frame


def test_transforms_follow_the_frame_conventions(small_scene_dir, small_scene):
    dem = io.read_raster(small_scene_dir / "truth_dem.tif")
    assert tuple(dem.transform)[:6] == (1.0, 0.0, -128.0, 0.0, -1.0, 128.0)
    np.testing.assert_array_equal(dem.data, small_scene.dem)
    target_dem = io.read_raster(small_scene_dir / "truth_dem_target.tif")
    assert tuple(target_dem.transform)[:6] == (0.5, 0.0, 0.0, 0.0, -0.5, 0.0)
    image = io.read_image(small_scene_dir / "view_01.tif")
    assert tuple(image.transform)[:6] == (1.0, 0.0, 0.0, 0.0, -1.0, 0.0)


def test_view_tags_carry_sun_and_view_vectors_in_the_grid_frame(small_scene_dir, small_scene):
    target = io.read_image(small_scene_dir / "view_00.tif")
    sun = np.asarray(target.tag_json("sun_vector"))
    np.testing.assert_allclose(sun, small_scene.sun_vector)
    np.testing.assert_allclose(target.tag_json("sun_vector_grid"), sun, atol=1e-12)  # nadir
    np.testing.assert_allclose(target.tag_json("view_vector_grid"), [0, 0, 1], atol=1e-12)
    assert float(target.tags["incidence_deg"]) == pytest.approx(60.0)
    assert float(target.tags["emission_deg"]) == pytest.approx(0.0, abs=1e-9)
    partner = io.read_image(small_scene_dir / "view_01.tif")
    camera = partner.tag_json("camera")
    R = np.asarray(camera["R"])
    grid_sun = R @ sun * [1, -1, -1]
    np.testing.assert_allclose(partner.tag_json("sun_vector_grid"), grid_sun, atol=1e-12)
    assert float(partner.tags["emission_deg"]) == pytest.approx(np.degrees(np.arctan(0.3)))
    assert partner.tags["view_name"] == "view_01"


def test_cameras_npz_and_scene_json_round_trip(small_scene_dir, small_scene):
    arrays = io.read_npz(small_scene_dir / "cameras.npz", "cameras")
    assert str(arrays["target"]) == "view_00" and str(arrays["partner"]) == "view_01"
    cameras = cameras_from_arrays(arrays)
    assert list(cameras) == list(small_scene.names)
    for name, camera in cameras.items():
        np.testing.assert_array_equal(camera.K, small_scene.cameras[name].K)
        np.testing.assert_array_equal(camera.R, small_scene.cameras[name].R)
        np.testing.assert_array_equal(camera.t, small_scene.cameras[name].t)
    scene = io.read_json(small_scene_dir / "scene.json")
    assert scene["target"] == "view_00" and scene["partner"] == "view_01"
    assert scene["distance_m"] == 1000.0 and scene["gsd_m"] == 0.5 and scene["seed"] == 0
    np.testing.assert_allclose(scene["sun_vector"], small_scene.sun_vector)
    assert scene["parameters"] == small_scene.params.as_dict()
    views = {v["name"]: v for v in scene["views"]}
    assert views["view_01"]["bh_to_target"] == pytest.approx(0.3)
    assert views["view_02"]["bh_to_target"] == pytest.approx(0.1)
    assert views["view_03"]["bh_to_target"] == pytest.approx(0.5)
    assert views["view_01"]["convergence_deg"] == pytest.approx(np.degrees(np.arctan(0.3)))
    assert scene["render_time_s"] > 0
    sidecar = io.read_json(small_scene_dir / "scene.json.json")
    assert sidecar["stage"] == "synth" and sidecar["summary"]["views"] == 4
    for name in scene["names"]:
        np.testing.assert_array_equal(io.read_image(small_scene_dir / f"{name}.tif").data,
                                      small_scene.images[name])


def test_saved_truth_and_camera_put_truth_points_on_their_pixels(small_scene_dir):
    """Ray of each target pixel ∩ its truth height lies on the saved DEM and reprojects."""
    cameras = cameras_from_arrays(io.read_npz(small_scene_dir / "cameras.npz", "cameras"))
    camera = cameras["view_00"]
    truth = io.read_raster(small_scene_dir / "truth_dem_target.tif").data.astype(np.float64)
    dem = io.read_raster(small_scene_dir / "truth_dem.tif")
    rows, cols = np.mgrid[0:camera.height:5, 0:camera.width:5]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    rays = camera.rays(pixels)
    z = truth[rows, cols].ravel()
    points = camera.center + ((z - camera.center[2]) / rays[:, 2])[:, None] * rays
    t = dem.transform
    dem_z = map_coordinates(dem.data.astype(np.float64),
                            [(points[:, 1] - t.f) / t.e - 0.5, (points[:, 0] - t.c) / t.a - 0.5],
                            order=1)
    np.testing.assert_allclose(dem_z, z, atol=2e-3)  # float32 storage of heights
    np.testing.assert_allclose(camera.project(points), pixels, atol=0.1)


def test_load_scene_restores_the_scene(small_scene_dir, small_scene):
    loaded = load_scene(small_scene_dir)
    assert loaded.names == small_scene.names and loaded.params == small_scene.params
    for name in loaded.names:
        np.testing.assert_allclose(loaded.depths[name], small_scene.depths[name], atol=1e-6)
        np.testing.assert_array_equal(loaded.shadows[name], small_scene.shadows[name])
    np.testing.assert_array_equal(loaded.truth_target, small_scene.truth_target)
    assert loaded.dn_per_reflectance == pytest.approx(small_scene.dn_per_reflectance)


def test_config_preset_sets_options_and_command_line_overrides(tmp_path):
    preset = tmp_path / "preset.toml"
    preset.write_text("[synth]\nviews = 2\nsun-incidence = 45.0\nnoise = false\n")
    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["--config", str(preset), "synth", "--out", str(out),
                                      *TINY_ARGS, "--views", "3"])
    assert result.exit_code == 0, result.output
    params = io.read_json(out / "scene.json")["parameters"]
    assert params["n_views"] == 3 and params["sun_incidence_deg"] == 45.0
    assert params["noise"] is False


@pytest.mark.parametrize("args, message", [
    (["--size", "0"], "--size"),
    (["--sun-incidence", "95"], "--sun-incidence"),
    (["--views", "1"], "--views"),
    (["--gsd", "-1"], "--gsd"),
    (["--albedo-variation", "1.2"], "--albedo-variation"),
    (["--craters", "5", "--no-craters"], "--no-craters"),
])
def test_bad_option_values_exit_2_and_write_nothing(tmp_path, args, message):
    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--out", str(out), *TINY_ARGS, *args])
    assert result.exit_code == 2
    assert message in result.output
    assert not out.exists()


@pytest.mark.parametrize("args, message", [
    (["--gsd", "3"], "sees ground up to"),
    (["--altitude", "5", "--gsd", "0.01"], "--altitude (5.0) must be above the highest"),
    (["--crater-min", "30", "--crater-max", "10"], "--crater-max must not be smaller than "
                                                   "--crater-min"),
    (["--bh-min", "0.4", "--bh-max", "0.2"], "--bh-max must not be smaller than --bh-min"),
])
def test_impossible_scenes_exit_1_with_one_line_and_write_nothing(tmp_path, args, message):
    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--out", str(out), *TINY_ARGS, *args])
    assert result.exit_code == 1
    lines = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(lines) == 1 and lines[0].startswith("Error: demtool synth:")
    assert message in lines[0]
    assert not out.exists()


def test_failure_while_writing_leaves_no_output(tmp_path, monkeypatch):
    from demtool import io as dio

    real = dio.write_npz

    def failing(*args, **kwargs):
        real(*args, **kwargs)
        raise OSError("disk full")

    monkeypatch.setattr(dio, "write_npz", failing)
    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--out", str(out), *TINY_ARGS])
    assert result.exit_code != 0
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
def test_sigterm_mid_run_leaves_no_output(tmp_path):
    out = tmp_path / "scene"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(
        [sys.executable, "-m", "demtool", "synth", "--out", str(out), "--views", "12",
         "--image-size", "400", "--size", "512"],
        stderr=subprocess.PIPE, text=True, env=env, cwd=Path(__file__).parents[2])
    started = time.monotonic()
    line = ""
    while "view_00 rendered" not in line:  # the run is under way: views are rendering
        line = process.stderr.readline()
        assert line or process.poll() is None, "demtool synth ended before rendering"
        assert time.monotonic() - started < 120
    process.send_signal(signal.SIGTERM)
    _, remaining = process.communicate(timeout=60)
    assert process.returncode != 0, remaining
    assert "Traceback" not in remaining
    assert not out.exists() or not list(out.iterdir())


def test_load_scene_names_a_missing_or_foreign_file(tmp_path):
    from demtool.errors import InputError

    with pytest.raises(InputError, match=r"scene\.json.*not found"):
        load_scene(tmp_path)
    (tmp_path / "scene.json").write_text('{"target": "a"}')
    with pytest.raises(InputError, match=r"scene\.json.*not a demtool synth scene"):
        load_scene(tmp_path)


# -- synth --sensor frame|linescan -----------------------------------------------------------

SENSOR_ARGS = ["--size", "128", "--views", "3", "--image-size", "64", "--gsd", "1",
               "--craters", "6", "--crater-max", "20", "--boulders", "10"]


@pytest.mark.parametrize("sensor, views", [("frame", 3), ("linescan", 2)])
def test_sensor_scenes_write_isds_and_the_map_truth(tmp_path, sensor, views):
    from demtool.maps import body_from_crs
    from demtool.sensors import read_sensor

    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--out", str(out), *SENSOR_ARGS, "--sensor",
                                      sensor, "--center-lon", "-60", "--center-lat", "75"])
    assert result.exit_code == 0, result.output
    names = [f"view_{i:02d}" for i in range(views)]
    expected = {f"{n}.{ext}" for n in names for ext in ("tif", "json")} | {
        "truth_dem.tif", "truth_dem_target.tif", "truth_dem_map.tif", "albedo.tif",
        "scene.json", "scene.json.json"} | ({"cameras.npz"} if sensor == "frame" else set())
    assert {p.name for p in out.iterdir()} == expected
    description = io.read_json(out / "scene.json")
    assert description["sensor"] == sensor
    assert description["body"]["body"] == "Moon"
    assert description["body"]["center_lat_deg"] == 75.0
    assert description["sensor_models"] == {n: f"{n}.json" for n in names}
    for name in names:
        model = read_sensor(out / f"{name}.json")
        assert model.kind == sensor and model.image_size == (64, 64)
        with rasterio.open(out / f"{name}.tif") as dataset:
            assert dataset.tags()["sensor_model"] == f"{name}.json"
    with rasterio.open(out / "truth_dem_map.tif") as dataset:
        assert body_from_crs(dataset.crs).name == "Moon"
        assert "Polar" in dataset.crs.to_wkt() or "Stereographic" in dataset.crs.to_wkt()
        assert dataset.res == pytest.approx((1.0, 1.0))
        assert dataset.tags()["height_reference"] == "sphere"
        heights = dataset.read(1)
    # the map is polar stereographic at 75° N, so the common footprint (a square in the
    # local frame) sits turned in its grid: check its area, 64 m × 64 m and more
    assert 0.8 * 64**2 < np.isfinite(heights).sum() < 1.3 * 64**2


@pytest.mark.parametrize("args, message, code", [
    (["--sensor", "frame", "--body", "Vulcan"], "--body", 1),
    (["--sensor", "linescan", "--image-size", "120"], "sees ground up to", 1),
    (["--sensor", "pushbroom"], "--sensor", 2),
    (["--sensor", "frame", "--center-lat", "95"], "--center-lat", 2),
    (["--sensor", "linescan", "--convergence", "0"], "--convergence", 2),
])
def test_bad_sensor_scenes_write_nothing(tmp_path, args, message, code):
    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--out", str(out), *SENSOR_ARGS, *args])
    assert result.exit_code == code
    assert message in result.output
    if code == 1:
        lines = [line for line in result.output.splitlines() if line.startswith("Error")]
        assert len(lines) == 1 and lines[0].startswith("Error: demtool synth:")
    assert not out.exists()
