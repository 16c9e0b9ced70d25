"""Tests of the disparity range's widening where SGM saturates at a bound (demtool.sgm.widen)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.sgm import sgm
from demtool.sgm.widen import (
    MIN_STEP_PX,
    is_saturated,
    saturated_bounds,
    sgm_widening,
    widened_range,
)
from tests.helpers.sgm import error_rates, smooth_disparity_pair, write_rectified_pair


@pytest.fixture(scope="module")
def far_pair():
    """A smooth pair whose disparities run 2 … 13 px (offset 6 ± 4, + 0 … 3 down)."""
    return smooth_disparity_pair(offset=6.0, amplitude=4.0)


def visible(truth: np.ndarray) -> np.ndarray:
    columns = np.arange(truth.shape[1])[None, :]
    return (columns - truth) >= 1


def test_saturated_bounds_count_pixels_exactly_at_each_bound():
    disparity = np.array([[-3.0, -3.0, -2.9, 5.0], [5.0, 5.0, np.nan, 4.99]])
    assert saturated_bounds(disparity, -3, 9) == (2, 3)
    assert is_saturated(32, 1000) and not is_saturated(31, 1000)
    assert not is_saturated(99, 2_000_000) and is_saturated(200, 2_000_000)


def test_widened_range_extends_only_the_saturated_side_and_fits_the_image():
    assert widened_range(-2, 9, False, True, 128) == (-2, 9 + MIN_STEP_PX)
    assert widened_range(-10, 21, True, False, 128) == (-20, 31)
    assert widened_range(-10, 21, True, True, 128) == (-20, 41)
    low, count = widened_range(-60, 121, True, True, 128)
    assert count < 128 and low > -128 and low + count - 1 < 128


def test_a_narrow_range_saturates_and_widening_recovers_the_far_disparities(far_pair):
    left, right, truth = far_pair
    narrow = sgm(left, right, min_disparity=-2, num_disparities=9, cost="census")
    at_low, at_high = saturated_bounds(narrow.disparity, -2, 9)
    assert at_high > 0.1 * truth.size > at_low  # disparities above 6 pile up at 6
    assert error_rates(narrow.disparity, truth, visible(truth))["bad2"] > 0.3

    result = sgm_widening(left, right, min_disparity=-2, num_disparities=9, widenings=3,
                          cost="census")
    history = result.parameters["range_widenings"]
    assert history and history[0]["from"] == [-2, 6] and history[0]["saturated_high"] == at_high
    assert history[0]["to"][1] == 6 + MIN_STEP_PX  # min … max: the upper side widened
    low, count = result.parameters["min_disparity"], result.parameters["num_disparities"]
    assert low <= -2 and low + count - 1 >= 14  # the range now covers the truth (≤ 13.1)
    rates = error_rates(result.disparity, truth, visible(truth))
    assert rates["bad2"] < 0.05 and rates["mae"] < 0.2, rates


def test_a_range_that_covers_the_disparities_is_matched_once(far_pair):
    left, right, truth = far_pair
    result = sgm_widening(left, right, min_disparity=-2, num_disparities=20, cost="census")
    assert result.parameters["range_widenings"] == []
    assert (result.parameters["min_disparity"], result.parameters["num_disparities"]) == (-2, 20)


def test_no_widening_when_told_so(far_pair):
    left, right, _ = far_pair
    result = sgm_widening(left, right, min_disparity=-2, num_disparities=9, widenings=0,
                          cost="census")
    assert result.parameters["range_widenings"] == []
    assert result.parameters["num_disparities"] == 9


@pytest.fixture(scope="module")
def far_pair_dir(tmp_path_factory, far_pair):
    """The far pair with a rectify.npz whose range (from 'matches') stops at 6 px."""
    folder = tmp_path_factory.mktemp("sgm_far")
    write_rectified_pair(folder, *far_pair, (-2.0, 6.0))
    return folder


def run_sgm(folder, out, *options, quiet=True):
    """``demtool sgm`` on the far pair (census cost) with ``options``."""
    return CliRunner().invoke(cli, [*(["-q"] if quiet else []), "sgm",
                                    str(folder / "left_rect.tif"),
                                    str(folder / "right_rect.tif"), "--cost", "census",
                                    *map(str, options), "--out", str(out)])


def test_cli_widens_an_estimated_range_and_says_so(far_pair_dir, tmp_path):
    out = tmp_path / "d.tif"
    result = run_sgm(far_pair_dir, out, "--rectify", far_pair_dir / "rectify.npz", quiet=False)
    assert result.exit_code == 0, result.output
    assert "upper bound -2 … 6" in result.output and "matching again over" in result.output
    raster = dio.read_raster(out)
    truth = np.load(far_pair_dir / "truth.npy")
    assert error_rates(raster.data, truth, visible(truth))["bad2"] < 0.05
    low, count = raster.tag_json("min_disparity"), raster.tag_json("num_disparities")
    assert low <= -2 and low + count - 1 >= 14
    summary = json.loads((tmp_path / "d.tif.json").read_text())["summary"]
    assert summary["range_widenings"][0]["from"] == [-2, 6]  # min … max, as logged
    assert summary["num_disparities"] == raster.tag_json("num_disparities")


def test_cli_never_widens_a_range_given_explicitly(far_pair_dir, tmp_path):
    out = tmp_path / "d.tif"
    result = run_sgm(far_pair_dir, out, "--min-disparity", -2, "--num-disparities", 9)
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "d.tif.json").read_text())["summary"]
    assert summary["range_widenings"] == [] and summary["num_disparities"] == 9


def test_cli_widen_range_zero_keeps_the_estimated_range(far_pair_dir, tmp_path):
    out = tmp_path / "d.tif"
    result = run_sgm(far_pair_dir, out, "--rectify", far_pair_dir / "rectify.npz",
                     "--widen-range", 0)
    assert result.exit_code == 0, result.output
    assert dio.read_raster(out).tag_json("num_disparities") == 9


def test_tiled_sgm_widens_each_saturated_tile(far_pair_dir, tmp_path):
    out = tmp_path / "d.tif"
    result = run_sgm(far_pair_dir, out, "--rectify", far_pair_dir / "rectify.npz",
                     "--tile-size", 64)
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "d.tif.json").read_text())["summary"]
    assert summary["tiles_widened"] >= 1
    assert max(high for _, high in summary["tile_ranges"]) >= 14  # min … max per tile
    truth = np.load(far_pair_dir / "truth.npy")
    assert error_rates(dio.read_raster(out).data, truth, visible(truth))["bad2"] < 0.05


def test_widening_stops_at_the_disparity_at_infinity():
    """A calibrated pair's lower side never goes below its disparity at infinity, and a
    side stuck at its limit does not trigger re-matches (sky, not terrain)."""
    assert widened_range(-10, 21, True, False, 128, lower_limit=-13) == (-13, 24)
    assert widened_range(-10, 21, True, True, 128, lower_limit=-10,
                         upper_limit=15) == (-10, 26)
    # never narrower than the range given
    assert widened_range(-10, 21, True, False, 128, lower_limit=-5) == (-10, 21)


def test_sgm_widening_respects_the_limits(far_pair):
    left, right, _ = far_pair
    result = sgm_widening(left, right, min_disparity=-2, num_disparities=9, widenings=3,
                          lower_limit=-2, upper_limit=6, cost="census")
    assert result.parameters["range_widenings"] == []  # both sides at their limits
    result = sgm_widening(left, right, min_disparity=-2, num_disparities=9, widenings=3,
                          lower_limit=-2, upper_limit=8, cost="census")
    low, count = result.parameters["min_disparity"], result.parameters["num_disparities"]
    assert low == -2 and low + count - 1 == 8
    assert [h["to"] for h in result.parameters["range_widenings"]] == [[-2, 8]]


def test_limits_from_rectification():
    from demtool.sgm.widen import limits_from_rectification

    assert limits_from_rectification({}) == (None, None)
    assert limits_from_rectification({"disparity_infinity": np.asarray(-3.4)}) == (-5, None)
    assert limits_from_rectification({"disparity_infinity": np.asarray(2.0),
                                      "disparity_nearest": np.asarray(40.2)}) == (1, 42)
