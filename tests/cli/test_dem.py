"""`demtool dem`: points route, disparity routes, grid helpers, projective fit, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.bundle import BundleResult
from demtool.cli import cli
from demtool.sensors.pinhole import PinholeCamera, cameras_to_arrays
from tests.helpers.dem import (
    BASELINE,
    RECTIFY,
    SIZE,
    nadir_camera,
    surface,
    synthetic_disparity,
    truth_grid,
)


def bundle_points(n: int = 4000, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-22, 22, (n, 2))  # inside the 48 m footprint
    return np.column_stack([xy, surface(xy[:, 0], xy[:, 1])])


def write_bundle(path: Path, points: np.ndarray, camera: PinholeCamera, *,
                 aligned: bool) -> Path:
    result = BundleResult(points=points, colors=np.zeros(len(points)),
                          track_length=np.full(len(points), 2),
                          reprojection_error=np.full(len(points), 0.2),
                          image_names=np.array(["view_00", "view_01"]),
                          cameras=[camera, nadir_camera(BASELINE)],
                          distortion=np.zeros((2, 2)), target_index=0, aligned=aligned)
    return dio.write_npz(path, "bundle", result.to_arrays())


def write_pair(folder: Path) -> dict[str, Path]:
    left, right = nadir_camera(), nadir_camera(BASELINE)
    disparity = synthetic_disparity(left, right)
    paths = {"disparity": folder / "disparity.tif", "rectify": folder / "rectify.npz",
             "cameras": folder / "cameras.npz", "reference": folder / "reference.tif"}
    dio.write_raster(paths["disparity"], disparity, tags={"frame": "image:view_00_rect"})
    dummy = np.zeros((4, 2))
    dio.write_npz(paths["rectify"], "rectification", {
        "H_left": RECTIFY, "H_right": RECTIFY, "F": np.zeros((3, 3)),
        "size_left": np.array([SIZE, SIZE]), "size_right": np.array([SIZE, SIZE]),
        "size_rect": np.array(disparity.shape[::-1]), "points_left": dummy,
        "points_right": dummy, "points_left_rect": dummy, "points_right_rect": dummy,
        "disparity_range": np.array([0.0, 700.0]), "left_name": np.asarray("view_00"),
        "right_name": np.asarray("view_01")})
    dio.write_npz(paths["cameras"], "cameras",
                  cameras_to_arrays(["view_00", "view_01"], [left, right]))
    dio.write_raster(paths["reference"], truth_grid(left) - 1.0,
                     transform=dio.image_frame_transform(0.5),
                     tags={"frame": "image:view_00"})
    return paths


def test_cli_points_route_writes_dem_mask_and_sidecar(tmp_path):
    camera = nadir_camera()
    bundle = write_bundle(tmp_path / "bundle.npz", bundle_points(), camera, aligned=True)
    out, mask = tmp_path / "dem.tif", tmp_path / "mask.tif"
    result = CliRunner().invoke(cli, ["-q", "dem", "--points", str(bundle), "--out", str(out),
                                      "--interpolated-mask", str(mask), "--mask-band",
                                      "--median", "3"])
    assert result.exit_code == 0, result.output
    dem = dio.read_raster(out)
    assert dem.tags["frame"] == "image:view_00"
    assert dem.tags["dem_route"] == "points-metric"
    assert dem.spacing[0] == pytest.approx(0.5, rel=5e-3)  # estimated: depth / focal
    assert np.isfinite(dem.data).all()
    truth = truth_grid(camera)
    assert np.abs(dem.data - truth)[12:-12, 12:-12].max() < 0.1
    band2 = dio.read_raster(out, band=2).data
    mask_file = dio.read_raster(mask).data
    np.testing.assert_array_equal(band2, mask_file)
    assert set(np.unique(mask_file)) == {0.0, 1.0}
    summary = json.loads((tmp_path / "dem.tif.json").read_text())["summary"]
    assert summary["route"] == "points-metric" and summary["points_in_target"] == 4000
    assert summary["interpolated_fraction"] == pytest.approx(float(mask_file.mean()))


def test_cli_points_route_distance_from_scene_and_gsd(tmp_path):
    camera = nadir_camera()
    bundle = write_bundle(tmp_path / "bundle.npz", bundle_points() * 0.01, camera,
                          aligned=False)
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"distance_m": 1000.0, "gsd_m": 0.25}))
    out = tmp_path / "dem.tif"
    result = CliRunner().invoke(cli, ["-q", "dem", "--points", str(bundle), "--scene",
                                      str(scene), "--out", str(out)])
    assert result.exit_code == 0, result.output
    dem = dio.read_raster(out)
    assert dem.tags["dem_route"] == "points-eq2" and dem.spacing[0] == 0.25
    assert float(dem.tags["distance_m"]) == 1000.0
    result = CliRunner().invoke(cli, ["-q", "dem", "--points", str(bundle), "--out",
                                      str(tmp_path / "other.tif")])
    assert result.exit_code == 1 and "--distance" in result.output
    assert not (tmp_path / "other.tif").exists()


@pytest.mark.parametrize("route", ["cameras", "reference"])
def test_cli_disparity_routes(tmp_path, route):
    paths = write_pair(tmp_path)
    out = tmp_path / "dem.tif"
    result = CliRunner().invoke(cli, ["-q", "dem", "--disparity", str(paths["disparity"]),
                                      "--rectify", str(paths["rectify"]), f"--{route}",
                                      str(paths[route]), "--out", str(out), "--mask-band"])
    assert result.exit_code == 0, result.output
    dem = dio.read_raster(out)
    measured = dio.read_raster(out, band=2).data == 0
    truth = truth_grid(nadir_camera()) - (1.0 if route == "reference" else 0.0)
    inner = np.zeros_like(measured)
    inner[3:-3, 3:-3] = True
    assert (measured & inner).mean() > 0.5
    assert np.abs(dem.data - truth)[measured & inner].max() < 0.02
    expected_route = "disparity-calibrated" if route == "cameras" else "disparity-projective"
    assert dem.tags["dem_route"] == expected_route
    assert dem.spacing[0] == pytest.approx(0.5, rel=5e-3)


def test_cli_usage_errors_exit_2(tmp_path):
    runner = CliRunner()
    out = str(tmp_path / "dem.tif")
    for args in ([], ["--points", "a.npz", "--disparity", "d.tif"],
                 ["--disparity", "d.tif", "--reference", "r.tif"],
                 ["--disparity", "d.tif", "--rectify", "r.npz", "--reference", "r.tif",
                  "--cameras", "c.npz"],
                 ["--points", "a.npz", "--median", "4"],
                 ["--points", "a.npz", "--cameras", "c.npz"]):
        result = runner.invoke(cli, ["dem", *args, "--out", out])
        assert result.exit_code == 2, (args, result.output)
    assert not Path(out).exists()


def test_cli_bad_inputs_exit_1_without_output(tmp_path):
    paths = write_pair(tmp_path)
    runner = CliRunner()
    out = tmp_path / "dem.tif"

    def run(*args):
        result = runner.invoke(cli, ["dem", *args, "--out", str(out)])
        assert result.exit_code == 1, result.output
        assert not out.exists() and not Path(f"{out}.json").exists()
        return result.output

    assert "missing.npz: input file not found" in run("--points", str(tmp_path / "missing.npz"))
    assert "is a cameras file, expected a bundle file" in run("--points", str(paths["cameras"]))
    nan_disparity = tmp_path / "nan.tif"
    dio.write_raster(nan_disparity, np.full((10, 10), np.nan))
    assert "no valid" in run("--disparity", str(nan_disparity), "--rectify",
                             str(paths["rectify"]), "--cameras", str(paths["cameras"]))
    assert "is not calibrated: give --reference or --cameras" in run(
        "--disparity", str(paths["disparity"]), "--rectify", str(paths["rectify"]))
    assert "--error-out belongs to the sensor-model route" in run(
        "--disparity", str(paths["disparity"]), "--rectify", str(paths["rectify"]),
        "--cameras", str(paths["cameras"]), "--error-out", str(tmp_path / "e.tif"))
    small_reference = tmp_path / "small.tif"
    dio.write_raster(small_reference, np.zeros((10, 10)), tags={"frame": "image:view_00"})
    assert "on the target's pixel grid" in run("--disparity", str(paths["disparity"]),
                                               "--rectify", str(paths["rectify"]),
                                               "--reference", str(small_reference))
    far = write_bundle(tmp_path / "far.npz", bundle_points(50) + [5000.0, 0, 0],
                       nadir_camera(), aligned=True)
    assert "none of the 50 points" in run("--points", str(far))
    few = write_bundle(tmp_path / "few.npz", bundle_points(6), nadir_camera(), aligned=True)
    assert "only 6 bundle points" in run("--points", str(few))
    assert "not among the registered" in run("--points", str(few), "--target", "nope")
    assert "neither the left" in run("--disparity", str(paths["disparity"]), "--rectify",
                                     str(paths["rectify"]), "--cameras",
                                     str(paths["cameras"]), "--target", "view_07")
