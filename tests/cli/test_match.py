"""Tests of `demtool match` through the command line (CliRunner)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.match import textured_pair


@pytest.fixture(scope="module")
def pair_files(tmp_path_factory):
    """A rectified pair on disk (tagged like demtool rectify's output) and its truth."""
    folder = tmp_path_factory.mktemp("match_pair")
    left, right, truth = textured_pair(80, 112, seed=3)
    for name, image in (("left_rect", left), ("right_rect", right)):
        dio.write_raster(folder / f"{name}.tif", image,
                         tags={"frame": f"image:{name}", "rectified_from": name[:-5]})
    return folder, truth


def _rectify_npz(path: Path, *, size_left, size_right, size_rect, H_left=None, H_right=None,
                 points_left_rect, points_right_rect):
    eye = np.eye(3)
    arrays = {
        "H_left": eye if H_left is None else H_left,
        "H_right": eye if H_right is None else H_right,
        "F": np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
        "size_left": np.asarray(size_left), "size_right": np.asarray(size_right),
        "size_rect": np.asarray(size_rect),
        "points_left": points_left_rect, "points_right": points_right_rect,
        "points_left_rect": points_left_rect, "points_right_rect": points_right_rect,
        "disparity_range": np.array([0.0, 16.0]),
        "left_name": np.asarray("left"), "right_name": np.asarray("right"),
    }
    dio.write_npz(path, "rectification", arrays)
    return path


def _seeds(truth: np.ndarray, step: int = 14) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[10:truth.shape[0] - 10:step, 20:truth.shape[1] - 10:step]
    left = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    right = left - np.column_stack([truth[yy, xx].ravel(), np.zeros(yy.size)])
    return left, right


def _invoke(args):
    return CliRunner().invoke(cli, ["-q", "match", *map(str, args)])


def test_match_cli_writes_disparity_correlation_sigma_and_sidecar(pair_files, tmp_path):
    folder, truth = pair_files
    out = tmp_path / "disparity.tif"
    result = _invoke([folder / "left_rect.tif", folder / "right_rect.tif", "--out", out,
                      "--template", "13", "--correlation-out", tmp_path / "corr.tif",
                      "--sigma-out", tmp_path / "sigma.tif", "--workers", "1"])
    assert result.exit_code == 0, result.output
    disparity = dio.read_raster(out, what="disparity")
    assert disparity.tags["frame"] == "image:left_rect"
    assert disparity.tags["disparity_convention"] == "x_right = x_left - d"
    ok = np.isfinite(disparity.data)
    assert ok.mean() > 0.5
    assert np.abs(disparity.data[ok] - truth[ok]).mean() < 0.05
    correlation = dio.read_raster(tmp_path / "corr.tif").data
    assert np.all(correlation[ok] >= 0.9)
    sigma = dio.read_raster(tmp_path / "sigma.tif").data
    assert np.isfinite(sigma[ok]).all() and np.isnan(sigma[~ok]).all()
    sidecar = json.loads(Path(f"{out}.json").read_text())
    assert sidecar["stage"] == "match"
    assert sidecar["parameters"]["template"] == 13
    summary = sidecar["summary"]
    assert summary["completeness_percent"] == pytest.approx(100 * ok.mean(), abs=0.01)
    assert summary["seeds"] >= 3 and summary["input_rectified_here"] is False
    assert set(sidecar["outputs"]) == {str(out), str(tmp_path / "corr.tif"),
                                       str(tmp_path / "sigma.tif")}


def test_match_cli_uses_rectify_seeds_for_a_rectified_pair(pair_files, tmp_path):
    folder, truth = pair_files
    pts_left, pts_right = _seeds(truth)
    npz = _rectify_npz(tmp_path / "rectify.npz", size_left=(112, 80), size_right=(112, 80),
                       size_rect=(112, 80), points_left_rect=pts_left,
                       points_right_rect=pts_right)
    out = tmp_path / "d.tif"
    result = _invoke([folder / "left_rect.tif", folder / "right_rect.tif", "--rectify", npz,
                      "--out", out, "--template", "13", "--no-sift"])
    assert result.exit_code == 0, result.output
    summary = json.loads(Path(f"{out}.json").read_text())["summary"]
    assert summary["seed_counts"]["prior"] == len(pts_left)
    assert summary["input_rectified_here"] is False
    data = dio.read_raster(out).data
    ok = np.isfinite(data)
    assert np.abs(data[ok] - truth[ok]).mean() < 0.05


def test_match_cli_warps_an_original_pair_with_rectify_npz(tmp_path):
    left, right, truth = textured_pair(80, 112, seed=4)
    # the original right image sits 3 rows lower; H_right moves it back up
    right_original = np.full((86, 112), np.nan, dtype=np.float32)
    right_original[3:83] = right
    dio.write_raster(tmp_path / "a.tif", left)
    dio.write_raster(tmp_path / "b.tif", right_original)
    H_right = np.array([[1.0, 0, 0], [0, 1, -3], [0, 0, 1]])
    pts_left, pts_right = _seeds(truth)
    npz = _rectify_npz(tmp_path / "rectify.npz", size_left=(112, 80), size_right=(112, 86),
                       size_rect=(112, 80), H_right=H_right, points_left_rect=pts_left,
                       points_right_rect=pts_right)
    out = tmp_path / "d.tif"
    result = _invoke([tmp_path / "a.tif", tmp_path / "b.tif", "--rectify", npz, "--out", out,
                      "--template", "13"])
    assert result.exit_code == 0, result.output
    disparity = dio.read_raster(out)
    assert disparity.tags["frame"] == "image:a_rect"
    assert disparity.data.shape == (80, 112)
    assert json.loads(Path(f"{out}.json").read_text())["summary"]["input_rectified_here"]
    ok = np.isfinite(disparity.data)
    assert ok.mean() > 0.5
    assert np.abs(disparity.data[ok] - truth[ok]).mean() < 0.05


def _assert_failed(result, exit_code: int, *fragments: str, folder: Path):
    assert result.exit_code == exit_code, result.output
    for fragment in fragments:
        assert fragment in result.output, result.output
    # neither the disparity nor its sidecar nor a temporary file is left behind
    assert not any("d.tif" in p.name for p in folder.iterdir()), list(folder.iterdir())


def test_match_cli_missing_file(pair_files, tmp_path):
    folder, _ = pair_files
    result = _invoke([tmp_path / "nope.tif", folder / "right_rect.tif", "--out",
                      tmp_path / "d.tif"])
    _assert_failed(result, 1, "nope.tif", "not found", folder=tmp_path)


def test_match_cli_sizes_differ(pair_files, tmp_path):
    folder, _ = pair_files
    dio.write_raster(tmp_path / "small.tif", np.ones((40, 50), np.float32))
    result = _invoke([folder / "left_rect.tif", tmp_path / "small.tif", "--out",
                      tmp_path / "d.tif"])
    _assert_failed(result, 1, "differ in size", folder=tmp_path)


def test_match_cli_all_nan_image(pair_files, tmp_path):
    folder, _ = pair_files
    dio.write_raster(tmp_path / "nan.tif", np.full((80, 112), np.nan, np.float32))
    result = _invoke([tmp_path / "nan.tif", folder / "right_rect.tif", "--out",
                      tmp_path / "d.tif"])
    _assert_failed(result, 1, "nan.tif", "no valid", folder=tmp_path)


@pytest.mark.parametrize("option, value, message", [
    ("--template", "16", "must be odd"),
    ("--template", "27", "9<=x<=25"),
    ("--threshold", "1.0", "0<x<1"),
    ("--grid-spacing", "0", "x>=1"),
    ("--levels", "0", "1<=x<=8"),
])
def test_match_cli_bad_options(pair_files, tmp_path, option, value, message):
    folder, _ = pair_files
    result = _invoke([folder / "left_rect.tif", folder / "right_rect.tif", "--out",
                      tmp_path / "d.tif", option, value])
    _assert_failed(result, 2, message, folder=tmp_path)


def test_match_cli_extra_output_same_as_out(pair_files, tmp_path):
    folder, _ = pair_files
    out = tmp_path / "d.tif"
    result = _invoke([folder / "left_rect.tif", folder / "right_rect.tif", "--out", out,
                      "--correlation-out", out])
    _assert_failed(result, 1, "--correlation-out", "same file", folder=tmp_path)


def test_match_cli_seeds_outside_the_image(pair_files, tmp_path):
    folder, truth = pair_files
    pts_left, pts_right = _seeds(truth)
    pts_left[0] = [400.0, 20.0]
    npz = _rectify_npz(tmp_path / "rectify.npz", size_left=(112, 80), size_right=(112, 80),
                       size_rect=(112, 80), points_left_rect=pts_left,
                       points_right_rect=pts_right)
    result = _invoke([folder / "left_rect.tif", folder / "right_rect.tif", "--rectify", npz,
                      "--out", tmp_path / "d.tif"])
    _assert_failed(result, 1, "rectify.npz", "outside", folder=tmp_path)


def test_match_cli_rectify_from_another_pair(pair_files, tmp_path):
    folder, truth = pair_files
    pts_left, pts_right = _seeds(truth)
    npz = _rectify_npz(tmp_path / "rectify.npz", size_left=(300, 200), size_right=(300, 200),
                       size_rect=(320, 210), points_left_rect=pts_left,
                       points_right_rect=pts_right)
    result = _invoke([folder / "left_rect.tif", folder / "right_rect.tif", "--rectify", npz,
                      "--out", tmp_path / "d.tif"])
    _assert_failed(result, 1, "rectify.npz", "from this pair", folder=tmp_path)


def test_match_cli_pair_without_seeds(tmp_path):
    ramp = np.tile(np.linspace(0, 1, 96, dtype=np.float32), (72, 1))
    dio.write_raster(tmp_path / "l.tif", ramp)
    dio.write_raster(tmp_path / "r.tif", ramp)
    result = _invoke([tmp_path / "l.tif", tmp_path / "r.tif", "--out", tmp_path / "d.tif",
                      "--template", "13"])
    _assert_failed(result, 1, "seed match", folder=tmp_path)
