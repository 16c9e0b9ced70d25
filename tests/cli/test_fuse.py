"""`demtool fuse`: DEMs on the Moon's map → fused DEM, count, spread, error; every bad input
(exit 1, one line naming the file, nothing written)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.fuse import write_dem, write_error

WINDOWS = [(0, 50, 0, 50), (10, 60, 8, 58)]
OUTPUTS = ("fused.tif", "fused_count.tif", "fused_spread.tif", "fused_error.tif",
           "fused.tif.json")


@pytest.fixture()
def dems(tmp_path):
    paths = []
    for i, window in enumerate(WINDOWS):
        paths.append(tmp_path / f"dem_{i}.tif")
        write_dem(paths[-1], window, noise=0.05, seed=i, shift=(0, 0, 0.5 * i))
    return paths


def invoke(*args):
    return CliRunner().invoke(cli, ["fuse", *map(str, args)])


def assert_nothing_written(folder):
    assert not [name for name in OUTPUTS if (folder / name).exists()]


def test_fuse_writes_dem_count_spread_error_and_logs_the_shift(dems, tmp_path):
    out = tmp_path / "fused.tif"
    result = invoke(*dems, "--out", out, "--blend", "4")
    assert result.exit_code == 0, result.output
    for name in OUTPUTS:
        assert (tmp_path / name).is_file(), name
    assert "dem_1.tif: shift to the reference" in result.stderr
    assert "dz -0.50" in result.stderr
    fused = dio.read_raster(out)
    assert fused.crs is not None and fused.tags["body"] == "Moon"
    assert fused.data.shape == (60, 58)
    count = dio.read_raster(tmp_path / "fused_count.tif").data
    assert count.max() == 2 and np.isnan(fused.data[count == 0]).all()
    sidecar = json.loads((tmp_path / "fused.tif.json").read_text())
    shift = sidecar["summary"]["dems"][1]["alignment"]["shift"]
    assert shift["dz"] == pytest.approx(-0.5, abs=0.03)


def test_different_bodies(dems, tmp_path):
    write_dem(tmp_path / "mars.tif", WINDOWS[0], body_id=499)
    result = invoke(dems[0], tmp_path / "mars.tif", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 1
    assert result.output.count("Error:") == 1 and "mars.tif: is on Mars" in result.output
    assert "Traceback" not in result.output
    assert_nothing_written(tmp_path)


def test_no_common_overlap(dems, tmp_path):
    write_dem(tmp_path / "far.tif", (100, 140, 100, 140))
    result = invoke(dems[0], tmp_path / "far.tif", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 1
    assert "far.tif: no common overlap with the reference" in result.output
    assert_nothing_written(tmp_path)


def test_median_names_the_dem_without_error_raster(dems, tmp_path):
    write_error(tmp_path / "e0.tif", WINDOWS[0], 0.2)
    result = invoke(*dems, "--method", "median", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 1
    assert "dem_0.tif: no error raster" in result.output and "--method median" in result.output
    assert_nothing_written(tmp_path)
    result = invoke(*dems, "--method", "median", "--error", tmp_path / "e0.tif",
                    "--out", tmp_path / "fused.tif")
    assert result.exit_code == 1 and "--error: 1 error raster(s) for 2 DEMs" in result.output
    assert_nothing_written(tmp_path)
    write_error(tmp_path / "e1.tif", WINDOWS[0], 0.2)  # on dem_0's grid, not dem_1's
    result = invoke(*dems, "--method", "median", "--error", tmp_path / "e0.tif", "--error",
                    tmp_path / "e1.tif", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 1 and "e1.tif: the error raster is not on" in result.output
    assert_nothing_written(tmp_path)


def test_every_dem_rejected(dems, tmp_path):
    result = invoke(*dems, "--align", "none", "--max-nmad", "0.01", "--out",
                    tmp_path / "fused.tif")
    assert result.exit_code == 1
    assert "every DEM was rejected as an outlier" in result.output
    assert_nothing_written(tmp_path)


def test_usage_errors_exit_2(dems, tmp_path):
    result = invoke(*dems, "--method", "mode", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 2
    result = invoke(*dems, "--outlier-k", "0.5", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 2
    assert_nothing_written(tmp_path)


def test_missing_dem(dems, tmp_path):
    result = invoke(dems[0], tmp_path / "nope.tif", "--out", tmp_path / "fused.tif")
    assert result.exit_code == 1 and "nope.tif" in result.output
    assert_nothing_written(tmp_path)
