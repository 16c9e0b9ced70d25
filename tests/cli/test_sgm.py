"""Tests of `demtool sgm` through the command line (CliRunner)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.sgm import error_rates, smooth_disparity_pair, write_rectified_pair

PRESETS = Path(__file__).resolve().parents[2] / "configs"


@pytest.fixture(scope="module")
def pair_dir(tmp_path_factory):
    """left_rect.tif / right_rect.tif of a smooth pair, its truth and a rectify.npz."""
    folder = tmp_path_factory.mktemp("sgm_pair")
    left, right, truth = smooth_disparity_pair(offset=0.0)
    left[:, :4] = np.nan  # outside the warped image
    write_rectified_pair(folder, left, right, truth, (-11.5, 11.2))
    return folder


def invoke(*args: str):
    return CliRunner().invoke(cli, ["-q", "sgm", *map(str, args)])


def test_cli_writes_disparity_confidence_and_sidecar(pair_dir, tmp_path):
    out = tmp_path / "disparity.tif"
    confidence = tmp_path / "confidence.tif"
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out", out,
                    "--rectify", pair_dir / "rectify.npz", "--confidence", confidence,
                    "--cost", "census", "--paths", "16")
    assert result.exit_code == 0, result.output
    raster = dio.read_raster(out)
    truth = np.load(pair_dir / "truth.npy")
    columns = np.arange(truth.shape[1])[None, :]
    rates = error_rates(raster.data, truth, (columns - truth >= 1) & (columns >= 4))
    assert rates["bad2"] < 0.05 and rates["density"] > 0.9, rates
    assert np.isnan(raster.data[:, :4]).all()
    assert raster.tags["frame"] == "image:view_00_rect"
    assert raster.tags["demtool_stage"] == "sgm"
    assert raster.tag_json("min_disparity") == -12  # floor(-11.5) from rectify.npz
    assert raster.tag_json("num_disparities") == 25  # -12 … ceil(11.2) = 12
    conf = dio.read_raster(confidence)
    assert np.array_equal(np.isnan(conf.data), np.isnan(raster.data))
    sidecar = json.loads((tmp_path / "disparity.tif.json").read_text())
    summary = sidecar["summary"]
    assert summary["min_disparity"] == -12 and summary["num_disparities"] == 25
    assert summary["resolved"]["paths"] == 16 and summary["resolved"]["cost"] == "census"
    assert 0.9 < summary["valid_fraction"] <= 1.0
    timings = summary["timings_s"]
    assert {"prepare", "match", "match_cpu", "postprocess", "total"} <= set(timings)
    assert 0 < timings["match"] <= timings["total"] and timings["match_cpu"] > 0
    assert sidecar["parameters"]["paths"] == 16
    assert sorted(sidecar["outputs"]) == sorted([str(out), str(confidence)])


def test_cli_default_auto_with_explicit_range(pair_dir, tmp_path):
    out, classes = tmp_path / "d.tif", tmp_path / "classes.tif"
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out", out,
                    "--min-disparity", "-12", "--num-disparities", "24", "--classes", classes)
    assert result.exit_code == 0, result.output
    sidecar = json.loads((tmp_path / "d.tif.json").read_text())
    summary = sidecar["summary"]
    assert summary["resolved"]["cost"] == "auto"
    assert summary["cost_used"] in ("hmi", "census", "hmi+census", "census+hmi")
    assert [p["scale"] for p in summary["passes"]][-1] == 1
    # what was matched, filled and left, separately; they add up to the valid input
    parts = [summary[f"{k}_fraction"] for k in ("matched", "at_range_bound",
                                                "filled_occlusion", "filled_mismatch",
                                                "invalid")]
    assert abs(sum(parts) - 1.0) < 2e-3 and summary["matched_fraction"] > 0.5
    assert summary["lr_consistent_fraction"] == pytest.approx(sum(parts[:2]), abs=2e-4)
    kinds = dio.read_raster(classes).data
    disparity = dio.read_raster(out).data
    assert np.array_equal(np.isfinite(disparity), kinds > 0)
    valid_input = np.isfinite(dio.read_raster(pair_dir / "left_rect.tif").data)
    matched = np.count_nonzero((kinds == 1) & valid_input) / valid_input.sum()
    assert abs(matched - summary["matched_fraction"]) < 2e-3
    truth = np.load(pair_dir / "truth.npy")
    columns = np.arange(truth.shape[1])[None, :]
    rates = error_rates(dio.read_raster(out).data, truth, (columns - truth >= 1) & (columns >= 4))
    assert rates["bad2"] < 0.05, rates


def _no_outputs(folder) -> bool:
    return not any(p.name.startswith(("d.tif", ".d.tif")) for p in folder.iterdir())


def test_cli_rejects_images_of_different_sizes(pair_dir, tmp_path):
    small = tmp_path / "small.tif"
    dio.write_raster(small, np.ones((90, 128), dtype=np.float32))
    result = invoke(pair_dir / "left_rect.tif", small, "--out", tmp_path / "d.tif",
                    "--rectify", pair_dir / "rectify.npz")
    assert result.exit_code == 1
    assert "differ in size" in result.output and "small.tif" in result.output
    assert _no_outputs(tmp_path)


def test_cli_rejects_a_nan_only_image(pair_dir, tmp_path):
    empty = tmp_path / "empty.tif"
    dio.write_raster(empty, np.full((96, 128), np.nan, dtype=np.float32))
    result = invoke(pair_dir / "left_rect.tif", empty, "--out", tmp_path / "d.tif",
                    "--rectify", pair_dir / "rectify.npz")
    assert result.exit_code == 1
    assert "empty.tif" in result.output and "no valid" in result.output
    assert _no_outputs(tmp_path)


def test_cli_rejects_a_disparity_range_wider_than_the_image(pair_dir, tmp_path):
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--min-disparity", "0", "--num-disparities", "500")
    assert result.exit_code == 1
    assert "wider than the images" in result.output
    assert _no_outputs(tmp_path)


def test_cli_needs_a_disparity_range(pair_dir, tmp_path):
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--min-disparity", "0")
    assert result.exit_code == 1
    assert "--rectify" in result.output and "--num-disparities" in result.output
    assert _no_outputs(tmp_path)


def test_cli_rejects_a_missing_or_wrong_rectify_file(pair_dir, tmp_path):
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--rectify", tmp_path / "nothing.npz")
    assert result.exit_code == 1 and "nothing.npz" in result.output
    matches = tmp_path / "matches.npz"
    dio.write_npz(matches, "matches", {"points_left": np.zeros((3, 2)),
                                       "points_right": np.zeros((3, 2)),
                                       "left_name": np.asarray("a"),
                                       "right_name": np.asarray("b")})
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--rectify", matches)
    assert result.exit_code == 1 and "expected a rectification file" in result.output
    assert _no_outputs(tmp_path)


def test_cli_missing_input(pair_dir, tmp_path):
    result = invoke(tmp_path / "absent.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--rectify", pair_dir / "rectify.npz")
    assert result.exit_code == 1
    assert "absent.tif" in result.output and "not found" in result.output
    assert _no_outputs(tmp_path)


@pytest.mark.parametrize("option, value", [("--paths", "4"), ("--cost", "ncc"),
                                           ("--cost-window", "4"), ("--median", "2"),
                                           ("--subpixel", "cubic"), ("--p1", "0"),
                                           ("--census-window", "3x3"),
                                           ("--mi-iterations", "0"), ("--uniqueness", "1.5")])
def test_cli_bad_option_values_are_usage_errors(pair_dir, tmp_path, option, value):
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--rectify", pair_dir / "rectify.npz", option, value)
    assert result.exit_code == 2
    assert option in result.output
    assert _no_outputs(tmp_path)


def test_cli_uniqueness_drops_ambiguous_pixels(pair_dir, tmp_path):
    fractions = []
    for name, extra in (("d.tif", []), ("u.tif", ["--uniqueness", "0.7"])):
        result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                        tmp_path / name, "--rectify", pair_dir / "rectify.npz", "--cost",
                        "census", "--no-fill", *extra)
        assert result.exit_code == 0, result.output
        fractions.append(np.isfinite(dio.read_raster(tmp_path / name).data).mean())
    assert fractions[1] < fractions[0]


def test_cli_penalties_out_of_order(pair_dir, tmp_path):
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--rectify", pair_dir / "rectify.npz", "--p1", "50",
                    "--p2", "10")
    assert result.exit_code == 1 and "P1" in result.output
    assert _no_outputs(tmp_path)


def test_cli_navcam_preset(pair_dir, tmp_path):
    result = CliRunner().invoke(cli, ["-q", "--config", str(PRESETS / "navcam.toml"), "sgm",
                                      str(pair_dir / "left_rect.tif"),
                                      str(pair_dir / "right_rect.tif"), "--out",
                                      str(tmp_path / "d.tif"), "--rectify",
                                      str(pair_dir / "rectify.npz")])
    assert result.exit_code == 0, result.output
    resolved = json.loads((tmp_path / "d.tif.json").read_text())["summary"]["resolved"]
    assert resolved["cost"] == "mi" and resolved["paths"] == 16
    assert resolved["mi_iterations"] == 3


def test_cli_classes_with_tiles_is_refused(pair_dir, tmp_path):
    result = invoke(pair_dir / "left_rect.tif", pair_dir / "right_rect.tif", "--out",
                    tmp_path / "d.tif", "--rectify", pair_dir / "rectify.npz", "--tile-size",
                    "64", "--classes", tmp_path / "c.tif")
    assert result.exit_code == 1
    assert "--classes" in result.output and "untiled" in result.output
    assert _no_outputs(tmp_path) and not (tmp_path / "c.tif").exists()
