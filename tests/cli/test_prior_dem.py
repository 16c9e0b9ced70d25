"""`sgm --prior-dem`: a calibrated pair matched around a prior DEM (the block's second
pass), against the synthetic frame scene's exact truth; and its bad inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.maps import body_by_name, make_projection
from tests.helpers.frame_scene import height_on_grid, make_frame_scene, write_frame_scene


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def first_pass(tmp_path_factory):
    """rectify → sgm → dem of a frame pair (B/H 0.3, GSD 5 m: 0.06 px of disparity per
    metre of height), and the truth on that DEM's grid."""
    from demtool.maps.grids import MapGrid

    scene = make_frame_scene(size=160, seed=7)
    folder = tmp_path_factory.mktemp("prior_dem")
    paths = write_frame_scene(scene, folder)
    rect = folder / "rect"
    run = _invoke("rectify", paths["left"], paths["right"], "--sensor-left",
                  paths["left_isd"], "--sensor-right", paths["right_isd"], "--out", rect)
    assert run.exit_code == 0, run.output
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--out", folder / "disparity.tif")
    assert run.exit_code == 0, run.output
    run = _invoke("dem", "--disparity", folder / "disparity.tif", "--rectify",
                  rect / "rectify.npz", "--out", folder / "dem.tif")
    assert run.exit_code == 0, run.output
    dem = dio.read_raster(folder / "dem.tif", what="DEM")
    grid = MapGrid(dem.crs, dem.transform, dem.data.shape[1], dem.data.shape[0])
    return scene, folder, rect, dem, height_on_grid(scene, grid)


def _second_pass(first_pass, prior_heights, name, tmp_path, *extra):
    scene, folder, rect, dem, truth = first_pass
    prior = tmp_path / f"{name}.tif"
    dio.write_raster(prior, prior_heights.astype(np.float32), transform=dem.transform,
                     crs=dem.crs, tags=dem.tags)
    out = tmp_path / f"{name}_disparity.tif"
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--prior-dem", prior, *extra, "--out", out)
    return run, out, prior


@pytest.mark.slow
@pytest.mark.parametrize("offset_m", [0.0, 30.0])
def test_prior_dem_matches_the_residual(first_pass, tmp_path, offset_m):
    """A prior 30 m too high (1.8 px of disparity) is corrected by the residual search:
    the second-pass DEM agrees with the truth as the first pass does, not with the prior."""
    scene, folder, rect, dem, truth = first_pass
    run, out, _ = _second_pass(first_pass, truth + offset_m, f"prior_{offset_m:g}", tmp_path)
    assert run.exit_code == 0, run.output
    summary = json.loads(out.with_name(out.name + ".json").read_text())["summary"]
    assert summary["prior_coverage_fraction"] > 0.95
    # residual ≈ −offset × 0.06 px/m: it measures what the prior got wrong
    assert summary["residual_median_px"] == pytest.approx(-0.06 * offset_m, abs=0.25)
    # the range written for dem is the total one: the prediction's extremes ± the search
    total = dio.read_raster(out, what="disparity")
    low, count = int(total.tags["min_disparity"]), int(total.tags["num_disparities"])
    predicted = summary["prior_disparity_range_px"]
    assert low == np.floor(predicted[0]) - 4 and low + count - 1 == np.ceil(predicted[1]) + 4
    values = total.data[np.isfinite(total.data)]
    assert values.min() >= low and values.max() <= low + count - 1
    run = _invoke("dem", "--disparity", out, "--rectify", rect / "rectify.npz",
                  "--out", tmp_path / "dem2.tif")
    assert run.exit_code == 0, run.output
    from demtool.maps.grids import MapGrid

    second = dio.read_raster(tmp_path / "dem2.tif", what="DEM")
    truth_second = height_on_grid(scene, MapGrid(second.crs, second.transform,
                                                 second.data.shape[1], second.data.shape[0]))
    assert np.isfinite(second.data).sum() >= 0.97 * np.isfinite(dem.data).sum()
    error_first = (dem.data - truth)[np.isfinite(dem.data)]
    error_second = (second.data - truth_second)[np.isfinite(second.data)]
    rmse_first = float(np.sqrt(np.mean(error_first ** 2)))
    rmse_second = float(np.sqrt(np.mean(error_second ** 2)))
    assert abs(float(np.median(error_second))) < 0.3 * scene.gsd_m  # not the prior's 30 m
    assert rmse_second < 0.6 * scene.gsd_m and rmse_second < 1.2 * rmse_first


@pytest.mark.slow
def test_prior_dem_bad_inputs(first_pass, tmp_path):
    scene, folder, rect, dem, truth = first_pass
    # a DEM of another body
    mars = make_projection(body_by_name("Mars"), "equirectangular", 10.0, 5.0)
    prior = tmp_path / "mars.tif"
    dio.write_raster(prior, truth.astype(np.float32), transform=dem.transform, crs=mars)
    out = tmp_path / "d.tif"
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--prior-dem", prior, "--out", out)
    assert run.exit_code == 1 and "mars.tif: is a DEM of Mars" in run.output
    assert not out.exists()
    # a DEM in an image's own frame (no CRS): not on the body's map
    prior = tmp_path / "frame.tif"
    dio.write_raster(prior, truth.astype(np.float32))
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--prior-dem", prior, "--out", out)
    assert run.exit_code == 1 and "frame.tif: DEM has no CRS" in run.output
    assert not out.exists()
    # a DEM that covers none of the image (its grid 100 km away)
    far = dem.transform.translation(20000, 0) @ dem.transform
    prior = tmp_path / "far.tif"
    dio.write_raster(prior, truth.astype(np.float32), transform=far, crs=dem.crs)
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--prior-dem", prior, "--out", out)
    assert run.exit_code == 1 and "far.tif: the prior DEM covers none of the left image" \
        in run.output
    assert not out.exists()
    # without the pair's rectification, with a range of its own, or a pair without models
    good = tmp_path / "good.tif"
    dio.write_raster(good, truth.astype(np.float32), transform=dem.transform, crs=dem.crs)
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--prior-dem", good,
                  "--out", out)
    assert run.exit_code == 1 and "give the pair's --rectify" in run.output
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  rect / "rectify.npz", "--prior-dem", good, "--min-disparity", "0",
                  "--num-disparities", "8", "--out", out)
    assert run.exit_code == 1 and "--min-disparity/--num-disparities" in run.output
    arrays = dict(np.load(rect / "rectify.npz", allow_pickle=True))
    arrays["calibrated"] = np.asarray(False)
    uncalibrated = tmp_path / "uncalibrated.npz"
    np.savez(uncalibrated, **arrays)
    run = _invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                  uncalibrated, "--prior-dem", good, "--out", out)
    assert run.exit_code == 1 and "uncalibrated.npz has no sensor models" in run.output
    assert not out.exists()


@pytest.mark.slow
def test_prior_dem_is_checked_against_the_pairs_matches(first_pass, tmp_path):
    """Issue 46: the prior is checked against the pair's own matches before it steers the
    search.  300 m too high (18 px, far beyond the ± 4 px search): moved by the measured
    offset (a warning says how much), and the disparity agrees with the first pass; an
    image given as the prior (brightness as heights): refused, naming it, nothing written."""
    scene, folder, rect, dem, truth = first_pass
    run, out, prior = _second_pass(first_pass, truth + 300.0, "prior_300", tmp_path)
    assert run.exit_code == 0, run.output
    assert "the prior is moved" in run.output and "off by -18" in run.output, run.output
    summary = json.loads(out.with_name(out.name + ".json").read_text())["summary"]
    assert summary["prior_correction_px"] == pytest.approx(-18.0, abs=0.5)
    first = dio.read_raster(folder / "disparity.tif").data
    second = dio.read_raster(out).data
    both = np.isfinite(first) & np.isfinite(second)
    assert both.mean() > 0.8 and np.median(np.abs(second - first)[both]) < 0.3
    image = np.random.default_rng(3).uniform(0, 255, truth.shape)
    run, out, prior = _second_pass(first_pass, image, "ortho_as_prior", tmp_path)
    assert run.exit_code == 1, run.output
    errors = [line for line in run.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1 and f"{prior}: disagrees with the" in errors[0], run.output
    assert not out.exists()
