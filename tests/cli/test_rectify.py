"""Tests of uncalibrated rectification (demtool.rectify.core, demtool rectify)."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.imaging.homography import (
    rectified_to_original,
)


@pytest.fixture(scope="module")
def pair_files(stereo_scene, tmp_path_factory):
    folder = tmp_path_factory.mktemp("pair")
    dio.write_raster(folder / "view_00.tif", stereo_scene.left)
    dio.write_raster(folder / "view_01.tif", stereo_scene.right)
    return folder / "view_00.tif", folder / "view_01.tif"


def test_cli_writes_rectified_pair(pair_files, tmp_path, stereo_scene):
    left, right = pair_files
    out = tmp_path / "stereo"
    run = CliRunner().invoke(cli, ["rectify", str(left), str(right), "--out", str(out),
                                   "--min-matches", "50"])
    assert run.exit_code == 0, run.output
    assert "RMS vertical residual" in run.output
    data = dio.read_npz(out / "rectify.npz", "rectification")
    assert str(data["left_name"]) == "view_00" and str(data["right_name"]) == "view_01"
    assert float(data["rms_vertical_residual"]) < 0.5
    width, height = data["size_rect"]
    left_rect = dio.read_raster(out / "left_rect.tif")
    right_rect = dio.read_raster(out / "right_rect.tif")
    assert left_rect.data.shape == right_rect.data.shape == (height, width)
    assert left_rect.tags["frame"] == "image:view_00_rect"
    assert right_rect.tags["frame"] == "image:view_01_rect"
    assert np.isnan(left_rect.data).any() and np.isfinite(left_rect.data).mean() > 0.5
    # the rectified image is the original resampled through H_left
    row, col = np.argwhere(np.isfinite(left_rect.data))[len(left_rect.data) * 3]
    x, y = rectified_to_original(np.array([[col, row]], float), data["H_left"])[0]
    expected = cv2.getRectSubPix(stereo_scene.left, (1, 1), (float(x), float(y)))[0, 0]
    assert left_rect.data[row, col] == pytest.approx(expected, rel=2e-3)
    sidecar = json.loads((out / "rectify.npz.json").read_text())
    assert sidecar["stage"] == "rectify"
    assert sidecar["summary"]["inliers"] == len(data["points_left"])
    assert sidecar["summary"]["rms_vertical_residual_px"] < 0.5
    assert sidecar["parameters"]["min_matches"] == 50


def test_cli_bad_inputs_leave_no_output(pair_files, tmp_path, stereo_scene):
    left, right = pair_files
    out = tmp_path / "out"
    runner = CliRunner()
    missing = runner.invoke(cli, ["rectify", str(left), str(tmp_path / "nope.tif"),
                                  "--out", str(out)])
    assert missing.exit_code == 1
    assert "nope.tif" in missing.output and "not found" in missing.output
    empty = tmp_path / "empty.tif"
    dio.write_raster(empty, np.full((64, 64), np.nan, np.float32))
    nan_only = runner.invoke(cli, ["rectify", str(left), str(empty), "--out", str(out)])
    assert nan_only.exit_code == 1 and "empty.tif" in nan_only.output
    assert "no valid" in nan_only.output
    same = runner.invoke(cli, ["rectify", str(left), str(left), "--out", str(out)])
    assert same.exit_code == 1 and "view_00.tif" in same.output
    errors = [line for line in same.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "identical" in errors[0]
    strict = runner.invoke(cli, ["rectify", str(left), str(right), "--out", str(out),
                                 "--min-matches", "100000"])
    assert strict.exit_code == 1 and "at least 100000" in strict.output
    bad_option = runner.invoke(cli, ["rectify", str(left), str(right), "--out", str(out),
                                     "--ratio", "1.5"])
    assert bad_option.exit_code == 2
    assert not out.exists() or not any(out.iterdir())


def test_cli_disparity_range_option(pair_files, tmp_path):
    left, right = pair_files
    out = tmp_path / "given"
    run = CliRunner().invoke(cli, ["rectify", str(left), str(right), "--out", str(out),
                                   "--disparity-range", "-5", "25"])
    assert run.exit_code == 0, run.output
    data = dio.read_npz(out / "rectify.npz", "rectification")
    np.testing.assert_array_equal(data["disparity_range"], [-5.0, 25.0])
    bad_out = tmp_path / "bad"
    bad = CliRunner().invoke(cli, ["rectify", str(left), str(right), "--out", str(bad_out),
                                   "--disparity-range", "25", "-5"])
    assert bad.exit_code == 1
    errors = [line for line in bad.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "--disparity-range" in errors[0]
    assert not bad_out.exists() or not any(bad_out.iterdir())


def test_rectify_refuses_two_images_on_one_map_grid(tmp_path):
    """A map-projected pair (same CRS and pixel size) is pointed to the map route."""
    from affine import Affine

    from demtool.maps import body_by_name, make_projection

    crs = make_projection(body_by_name("Moon"), "equirectangular", 10.0, 5.0)
    rng = np.random.default_rng(0)
    paths = []
    for k in range(2):
        path = tmp_path / f"ortho_{k}.tif"
        dio.write_raster(path, rng.random((64, 64)), crs=crs,
                         transform=Affine(1.0, 0, 100.0 + k, 0, -1.0, 5000.0))
        paths.append(path)
    out = tmp_path / "rect"
    result = CliRunner().invoke(cli, ["rectify", str(paths[0]), str(paths[1]), "--out",
                                      str(out)])
    assert result.exit_code == 1, result.output
    errors = [ln for ln in result.output.splitlines() if ln.startswith("Error")]
    assert len(errors) == 1 and "same map grid" in errors[0] and "--mapprojected" in errors[0]
    assert str(paths[0]) in errors[0]
    assert not out.exists()


# ------------------------------------------------- issue 12: turns the matches must show


def test_cli_turns_a_pair_whose_baseline_runs_along_the_columns(stereo_scene, tmp_path):
    """The stereo scene transposed: its baseline is vertical, and the ~80° turn is kept."""
    from demtool.rectify.core import rotation_at_centre

    folder = tmp_path / "columns"
    folder.mkdir()
    dio.write_raster(folder / "top.tif", np.ascontiguousarray(stereo_scene.left.T))
    dio.write_raster(folder / "bottom.tif", np.ascontiguousarray(stereo_scene.right.T))
    out = tmp_path / "stereo"
    run = CliRunner().invoke(cli, ["rectify", str(folder / "top.tif"),
                                   str(folder / "bottom.tif"), "--out", str(out)])
    assert run.exit_code == 0, run.output
    assert "the baseline is not along the rows" in run.output
    data = dio.read_npz(out / "rectify.npz", "rectification")
    turn = rotation_at_centre(data["H_left"], data["size_left"])
    assert 70 < abs(turn) < 100
    sidecar = json.loads((out / "rectify.npz.json").read_text())
    assert sidecar["summary"]["turn_deg"][0] == pytest.approx(turn, abs=0.01)
    assert float(data["rms_vertical_residual"]) < 0.5
    # the canvas stays the images' size, not inflated by the turn
    assert np.prod(data["size_rect"]) < 1.5 * np.prod(data["size_left"])


def test_cli_refuses_to_turn_aligned_images(stereo_scene, tmp_path):
    """Issue 12's HiRISE symptom: two aligned images (sub-pixel parallax) turned by 90°."""
    height, width = stereo_scene.left.shape
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    dy = 0.6 * np.sin(2 * np.pi * xx / 97.0) * np.cos(2 * np.pi * yy / 131.0)
    shifted = cv2.remap(stereo_scene.left.astype(np.float32), xx, yy + dy, cv2.INTER_CUBIC)
    folder = tmp_path / "aligned"
    folder.mkdir()
    dio.write_raster(folder / "ortho_a.tif", stereo_scene.left)
    dio.write_raster(folder / "ortho_b.tif", shifted)
    out = tmp_path / "out"
    run = CliRunner().invoke(cli, ["rectify", str(folder / "ortho_a.tif"),
                                   str(folder / "ortho_b.tif"), "--out", str(out)])
    assert run.exit_code == 1
    errors = [line for line in run.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1
    assert "ortho_a.tif" in errors[0] and "ortho_b.tif" in errors[0]
    assert re.search(r"turn the images by -?9\d°", errors[0]) and "mapproject" in errors[0]
    assert not out.exists() or not any(out.iterdir())
