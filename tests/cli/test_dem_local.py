"""`demtool dem` on a calibrated pair with no body: rectify --sensor-* → sgm → local DEM."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.rover import local_dem_errors, write_rover_pair


def _invoke(*args: str):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.mark.slow
@pytest.mark.parametrize("z_down", [False, True])
def test_rover_pair_reaches_a_local_dem(tmp_path, z_down):
    scene = write_rover_pair(tmp_path, supersample=1, z_down=z_down)
    cameras = tmp_path / "cameras.npz"
    rect = tmp_path / "rect"
    result = _invoke("rectify", tmp_path / "left.tif", tmp_path / "right.tif",
                     "--sensor-left", cameras, "--sensor-right", cameras, "--out", rect)
    assert result.exit_code == 0, result.output
    result = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                     rect / "rectify.npz", "--no-fill", "--out", tmp_path / "disp.tif")
    assert result.exit_code == 0, result.output
    up = ["--up", "0,0,-1"] if z_down else []
    result = _invoke("dem", "--disparity", tmp_path / "disp.tif", "--rectify",
                     rect / "rectify.npz", *up, "--points-out", tmp_path / "points.ply",
                     "--interpolated-mask", tmp_path / "mask.tif", "--error-out",
                     tmp_path / "gap.tif", "--out", tmp_path / "dem.tif")
    assert result.exit_code == 0, result.output
    mask, gap = dio.read_raster(tmp_path / "mask.tif"), dio.read_raster(tmp_path / "gap.tif")
    for extra in (mask, gap):
        assert extra.crs is None and extra.tags["frame"] == "map:local"
        assert extra.transform == dio.read_raster(tmp_path / "dem.tif").transform
    assert np.nanmax(mask.data) == 1 and np.nanmin(mask.data) == 0
    dem = dio.read_raster(tmp_path / "dem.tif")
    assert dem.crs is None and dem.tags["frame"] == "map:local"
    np.testing.assert_allclose([float(v) for v in dem.tags["local_up"].split(",")], scene.up)
    errors = local_dem_errors(tmp_path / "dem.tif", scene)
    assert errors["cells"] > 20000
    assert errors["rmse_m"] < 0.01 * errors["median_range_m"]
    assert errors["behind_camera"] == 0
    # the ground where the cameras say: the camera's height above a fitted plane
    assert abs(errors["camera_above_plane_m"] - errors["camera_above_plane_truth_m"]) < 0.02
    summary = json.loads((tmp_path / "dem.tif.json").read_text())["summary"]
    assert summary["route"] == "disparity-local" and "behind_camera" in summary
    header = (tmp_path / "points.ply").read_bytes()[:400]
    assert f"element vertex {summary['points']}".encode() in header


def test_up_and_points_out_belong_to_the_disparity_form(tmp_path):
    for extra in (["--up", "0,0,1"], ["--points-out", str(tmp_path / "p.ply")]):
        result = _invoke("dem", "--points", tmp_path / "bundle.npz", *extra, "--out",
                         tmp_path / "dem.tif")
        assert result.exit_code == 2, result.output
        assert "Traceback" not in result.output
    for bad in ("1,2", "0,0,0", "a,b,c"):
        result = _invoke("dem", "--disparity", tmp_path / "d.tif", "--rectify",
                         tmp_path / "r.npz", "--up", bad, "--out", tmp_path / "dem.tif")
        assert result.exit_code == 2, result.output
        assert "--up" in result.output
    assert not list(tmp_path.iterdir())


def test_sgm_fill_is_recognised_from_the_disparity_tags():
    from demtool.dem.run_local import _sgm_filled

    assert _sgm_filled({"demtool_stage": "sgm", "demtool_params": '{"fill": true}'})
    assert not _sgm_filled({"demtool_stage": "sgm", "demtool_params": '{"fill": false}'})
    assert not _sgm_filled({"demtool_stage": "match", "demtool_params": '{"fill": true}'})
    assert not _sgm_filled({"demtool_stage": "sgm", "demtool_params": "not json"})
