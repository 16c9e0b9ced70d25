"""Tests of `demtool refine` through the command line (CliRunner) on files in tmp_path."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io
from demtool.cli import cli
from tests.helpers.refine import hills_scene, rmse, slope_error

GSD = 0.5


@pytest.fixture(scope="module")
def scene():
    return hills_scene(size=96, spacing=GSD)


def write_inputs(folder: Path, scene, *, sun=None, dem=None, image=None,
                 image_transform=None, dem_transform=None, view="view_00") -> tuple[Path, Path]:
    """An image (pixel frame, synth-style tags) and a DEM (image frame, GSD spacing)."""
    image_path = folder / f"{view}.tif"
    dem_path = folder / "dem.tif"
    sun = scene.sun if sun is None else sun
    io.write_raster(image_path, scene.image if image is None else image,
                    transform=image_transform or io.image_frame_transform(1.0),
                    tags={"frame": f"image:{view}", "sun_vector_grid": list(sun),
                          "view_vector_grid": [0.0, 0.0, 1.0], "units": "DN"})
    io.write_raster(dem_path, scene.coarse if dem is None else dem,
                    transform=dem_transform or io.image_frame_transform(GSD),
                    tags={"frame": "image:view_00", "units": "m", "source": "test"})
    return image_path, dem_path


def invoke(*args: str):
    return CliRunner().invoke(cli, ["refine", *map(str, args)])


def test_refine_writes_a_better_dem_sidecar_and_albedo(tmp_path, scene):
    image, dem = write_inputs(tmp_path, scene)
    out = tmp_path / "out" / "refined.tif"
    albedo = tmp_path / "out" / "albedo.tif"
    result = invoke(image, dem, "--out", out, "--albedo-out", albedo, "--median", "0",
                    "--iterations", "40")
    assert result.exit_code == 0, result.output
    refined = io.read_raster(out)
    assert refined.data.shape == scene.coarse.shape
    assert refined.transform == io.image_frame_transform(GSD)
    assert refined.tags["frame"] == "image:view_00" and refined.tags["source"] == "test"
    assert refined.tags["demtool_stage"] == "refine"
    assert refined.tag_json("refine_iterations") >= 1
    assert set(refined.tag_json("refine_energies")) >= {"intensity", "integrability", "total"}
    assert rmse(refined.data, scene.truth) < 0.5 * rmse(scene.coarse, scene.truth)
    assert slope_error(refined.data, scene.truth, GSD) < 0.5 * slope_error(scene.coarse,
                                                                           scene.truth, GSD)
    sidecar = json.loads(Path(f"{out}.json").read_text())
    summary = sidecar["summary"]
    assert summary["sun_source"].startswith("tag sun_vector_grid")
    assert abs(summary["mean_height_shift_m"]) < 1e-3
    assert summary["energies_final"]["total"] < summary["energies_initial"]["total"]
    assert sidecar["parameters"]["tau"] == 10.0
    assert io.read_raster(albedo).data.shape == scene.coarse.shape
    timings = summary["timings_s"]  # wall and CPU seconds per phase
    assert all(timings[phase] >= 0 and timings[f"{phase}_cpu"] >= 0
               for phase in ("prepare_dem", "sfs", "write"))


def test_sun_from_options_overrides_tags(tmp_path, scene):
    # the tag says the sun is below the horizon; the options give the right one
    image, dem = write_inputs(tmp_path, scene, sun=[0.3, 0.2, -0.5])
    out = tmp_path / "refined.tif"
    azimuth = float(np.degrees(np.arctan2(scene.sun[0], scene.sun[1])))
    elevation = float(np.degrees(np.arcsin(scene.sun[2])))
    result = invoke(image, dem, "--out", out, "--sun-azimuth", azimuth, "--sun-elevation",
                    elevation, "--iterations", "5", "--median", "0")
    assert result.exit_code == 0, result.output
    summary = json.loads(Path(f"{out}.json").read_text())["summary"]
    assert np.allclose(summary["sun_vector_grid"], scene.sun, atol=1e-6)
    vector = ",".join(f"{v:.6f}" for v in scene.sun)
    result = invoke(image, dem, "--out", out, "--sun-vector", vector, "--iterations", "2")
    assert result.exit_code == 0, result.output


def test_image_on_another_grid_is_resampled_with_a_warning(tmp_path, scene, caplog):
    from scipy import ndimage

    # the image at twice the DEM's resolution, in pixel units over the same footprint
    fine = ndimage.zoom(scene.image, 2, order=1)
    image, dem = write_inputs(tmp_path, scene, image=fine)
    out = tmp_path / "refined.tif"
    logging.getLogger("demtool").propagate = True
    try:
        with caplog.at_level(logging.WARNING, logger="demtool"):
            result = invoke(image, dem, "--out", out, "--median", "0", "--iterations", "30")
    finally:
        logging.getLogger("demtool").propagate = False
    assert result.exit_code == 0, result.output
    assert any("different grids" in r.message and r.levelno == logging.WARNING
               for r in caplog.records)
    refined = io.read_raster(out).data
    assert rmse(refined, scene.truth) < 0.7 * rmse(scene.coarse, scene.truth)


def test_dem_gaps_are_filled_then_refined(tmp_path, scene):
    dem = scene.coarse.copy()
    dem[30:40, 50:60] = np.nan
    image, dem_path = write_inputs(tmp_path, scene, dem=dem)
    out = tmp_path / "refined.tif"
    result = invoke(image, dem_path, "--out", out, "--median", "0", "--iterations", "30")
    assert result.exit_code == 0, result.output
    refined = io.read_raster(out).data
    assert np.isfinite(refined).all()
    assert rmse(refined[30:40, 50:60], scene.truth[30:40, 50:60]) < 0.6 * rmse(
        scene.coarse[30:40, 50:60], scene.truth[30:40, 50:60])


def assert_failed(result, *fragments: str, code: int = 1, folder: Path | None = None):
    assert result.exit_code == code, result.output
    for fragment in fragments:
        assert fragment in result.output, result.output
    if folder is not None:
        assert not list(folder.glob("refined*")) and not list(folder.glob(".refined*"))


def test_nan_only_dem_is_refused(tmp_path, scene):
    image, dem = write_inputs(tmp_path, scene, dem=np.full(scene.coarse.shape, np.nan))
    result = invoke(image, dem, "--out", tmp_path / "refined.tif")
    assert_failed(result, "Error: demtool refine:", "dem.tif", "no valid", folder=tmp_path)


def test_too_many_gaps_are_refused(tmp_path, scene):
    dem = scene.coarse.copy()
    dem[:40] = np.nan
    image, dem_path = write_inputs(tmp_path, scene, dem=dem)
    result = invoke(image, dem_path, "--out", tmp_path / "refined.tif")
    assert_failed(result, "dem.tif", "--max-nan-fraction", folder=tmp_path)


def test_sun_below_the_horizon_is_refused(tmp_path, scene):
    image, dem = write_inputs(tmp_path, scene, sun=[0.5, 0.5, -0.2])
    result = invoke(image, dem, "--out", tmp_path / "refined.tif")
    assert_failed(result, "sun_vector_grid", "below the horizon", folder=tmp_path)
    result = invoke(image, dem, "--out", tmp_path / "refined.tif", "--sun-azimuth", "90",
                    "--sun-elevation", "-5")
    assert_failed(result, "--sun-elevation", "below the horizon", folder=tmp_path)
    result = invoke(image, dem, "--out", tmp_path / "refined.tif", "--sun-vector", "1,0,0")
    assert_failed(result, "--sun-vector", "below the horizon", folder=tmp_path)


def test_missing_sun_is_refused(tmp_path, scene):
    image = tmp_path / "plain.tif"
    io.write_raster(image, scene.image)
    _, dem = write_inputs(tmp_path, scene)
    result = invoke(image, dem, "--out", tmp_path / "refined.tif")
    assert_failed(result, "plain.tif", "no sun direction", "--sun-azimuth", folder=tmp_path)


def test_grids_that_do_not_overlap_are_refused(tmp_path, scene):
    from affine import Affine

    image, dem = write_inputs(tmp_path, scene,
                              image_transform=Affine(GSD, 0, 1e5, 0, -GSD, 0))
    result = invoke(image, dem, "--out", tmp_path / "refined.tif")
    assert_failed(result, "view_00.tif", "does not overlap", folder=tmp_path)


def test_image_of_another_view_is_refused(tmp_path, scene):
    image, dem = write_inputs(tmp_path, scene, view="view_03")
    result = invoke(image, dem, "--out", tmp_path / "refined.tif")
    assert_failed(result, "view_03.tif", "image:view_03", folder=tmp_path)


def test_missing_files_are_refused(tmp_path, scene):
    image, dem = write_inputs(tmp_path, scene)
    result = invoke(tmp_path / "nope.tif", dem, "--out", tmp_path / "refined.tif")
    assert_failed(result, "nope.tif", "not found", folder=tmp_path)
    result = invoke(image, tmp_path / "nodem.tif", "--out", tmp_path / "refined.tif")
    assert_failed(result, "nodem.tif", "not found", folder=tmp_path)


@pytest.mark.parametrize("args, message", [
    (["--sun-azimuth", "30"], "both --sun-azimuth and --sun-elevation"),
    (["--sun-vector", "1,2"], "three numbers"),
    (["--sun-vector", "0,0,0"], "zero length"),
    (["--sun-vector", "0,0,1", "--sun-azimuth", "3", "--sun-elevation", "40"], "either"),
    (["--median", "4"], "odd"),
    (["--spike-threshold", "-1"], "--spike-threshold"),
    (["--start-sigma", "-2"], "--start-sigma"),
    (["--shadow-weight", "-0.1"], "--shadow-weight"),
    (["--model", "hapke"], "lunar-lambert"),
    (["--gamma", "0"], "--gamma"),
    (["--shadow-threshold", "1.5"], "--shadow-threshold"),
])
def test_bad_options_are_usage_errors(tmp_path, scene, args, message):
    image, dem = write_inputs(tmp_path, scene)
    result = invoke(image, dem, "--out", tmp_path / "refined.tif", *args)
    assert_failed(result, message, code=2, folder=tmp_path)


def test_spikes_are_removed_and_reported(tmp_path, scene):
    """Blunders of the coarse DEM are replaced by the median in the anchor; the rest of
    the DEM keeps its relief (no 15-px flattening of the heights that Edepth holds)."""
    dem = scene.coarse.copy()
    dem[20, 30] += 40.0
    dem[60:62, 70:72] -= 25.0
    image, dem_path = write_inputs(tmp_path, scene, dem=dem)
    out = tmp_path / "refined.tif"
    result = invoke(image, dem_path, "--out", out, "--iterations", "30")
    assert result.exit_code == 0, result.output
    refined = io.read_raster(out).data
    assert abs(refined[20, 30] - scene.truth[20, 30]) < 1.0
    assert np.abs(refined[60:62, 70:72] - scene.truth[60:62, 70:72]).max() < 1.0
    assert rmse(refined, scene.truth) < 0.5 * rmse(scene.coarse, scene.truth)
    sidecar = json.loads(Path(f"{out}.json").read_text())
    assert 5 / dem.size <= sidecar["summary"]["dem_spike_fraction"] < 0.01
    assert sidecar["parameters"]["spike_threshold"] == 4.0
    assert sidecar["parameters"]["start_sigma"] == 2.0
    assert sidecar["parameters"]["shadow_weight"] == 0.005


@pytest.mark.parametrize("preset", ["configs/navcam.toml", "configs/lro-nac.toml"])
def test_study_presets_set_the_refine_parameters(preset):
    from demtool.cli import stage_options
    from demtool.commands.config import load_config, to_default_map

    root = Path(__file__).resolve().parents[2]
    defaults = to_default_map(load_config(root / preset), preset, stage_options)["refine"]
    assert defaults["albedo_sigma"] == 21 and defaults["lowpass_sigma"] == 21
    assert (defaults["delta"], defaults["gamma"], defaults["tau"]) == (0.001, 0.2, 10)
    assert defaults["median"] == 15 and defaults["model"] == "lunar-lambert"
    assert defaults["spike_threshold"] == 0  # the study's median applies to every pixel


@pytest.mark.slow
def test_refine_on_the_synthetic_scene(small_scene_dir, tmp_path):
    """End to end on `demtool synth` output: the truth smoothed (σ = 6 px) plus noise."""
    from scipy import ndimage

    truth = io.read_raster(small_scene_dir / "truth_dem_target.tif")
    rng = np.random.default_rng(0)
    coarse = ndimage.gaussian_filter(truth.data.astype(float), 6) + rng.normal(
        0, 0.2 * truth.spacing[0], truth.data.shape)
    dem = tmp_path / "coarse.tif"
    io.write_raster(dem, coarse, transform=truth.transform, tags=truth.tags)
    out = tmp_path / "refined.tif"
    result = invoke(small_scene_dir / "view_00.tif", dem, "--out", out, "--median", "0")
    assert result.exit_code == 0, result.output
    refined = io.read_raster(out).data
    assert rmse(refined, truth.data) < 0.7 * rmse(coarse, truth.data)
    assert abs(float(np.mean(refined - coarse))) < 0.1 * truth.spacing[0]


def test_refine_workers_leave_the_callers_numba_threads_as_they_were(tmp_path, scene):
    """``refine --workers 1`` bounds numba's threads for its own run only: an in-process
    caller (a CliRunner, a notebook, a chain of stages) keeps its count after it."""
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one numba thread: nothing to restore")
    image, dem = write_inputs(tmp_path, scene)
    before = numba.get_num_threads()
    result = invoke(image, dem, "--out", tmp_path / "r.tif", "--median", "0",
                    "--iterations", "3", "--workers", "1")
    assert result.exit_code == 0, result.output
    assert io.read_raster(tmp_path / "r.tif").data.shape == scene.coarse.shape
    assert numba.get_num_threads() == before
