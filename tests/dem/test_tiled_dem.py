"""``demtool dem`` in tiles (demtool.dem.tiled): tiled and untiled DEMs agree.

A paraboloid seen by two nadir cameras (tests/helpers/dem.py, exact disparities) with a
wide hole, a strip across the image and 1 % wild disparities keeps the checks fast and
the truth known; the small synthetic scene runs the whole chain (rectify → sgm → dem).

Tolerances achieved (tiles of 32 px, 9 tiles): with the coarse solve at full resolution
(grids up to ``COARSE_MAX_CELLS`` cells) the tiled DEM equals the untiled one within
1e-5 m everywhere and has the same interpolation mask; with the coarse solve decimated 4×
(16 px overlap, one Schwarz sweep) within 0.01 m (0.02 GSD) on 100 % of the cells
(≥ 99.5 % asserted), same completeness, same RMSE against the truth within 3 mm.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool import tiling
from demtool.cli import cli
from demtool.dem import tiled as tiled_dem
from demtool.dem import tiled_grids as dem_grids
from demtool.sensors.pinhole import cameras_to_arrays
from tests.helpers.dem import (
    BASELINE,
    RECTIFY,
    SIZE,
    nadir_camera,
    synthetic_disparity,
    truth_grid,
)

TILE = ["--tile-size", "32"]  # 9 tiles on the 96 × 96 target


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> Path:
    """disparity.tif, rectify.npz, cameras.npz of the paraboloid pair, with gaps."""
    folder = tmp_path_factory.mktemp("tiled_dem_pair")
    left, right = nadir_camera(), nadir_camera(BASELINE)
    disparity = synthetic_disparity(left, right)
    disparity[20:50, 40:75] = np.nan  # a wide hole
    disparity[60:64, :] = np.nan  # a strip across the image
    rng = np.random.default_rng(0)
    wild = rng.random(disparity.shape) < 0.01
    disparity[wild] += rng.normal(0.0, 5.0, int(wild.sum()))
    dio.write_raster(folder / "disparity.tif", disparity.astype(np.float32),
                     tags={"frame": "image:view_00_rect"})
    dummy = np.zeros((4, 2))
    dio.write_npz(folder / "rectify.npz", "rectification", {
        "H_left": RECTIFY, "H_right": RECTIFY, "F": np.zeros((3, 3)),
        "size_left": np.array([SIZE, SIZE]), "size_right": np.array([SIZE, SIZE]),
        "size_rect": np.array(disparity.shape[::-1]), "points_left": dummy,
        "points_right": dummy, "points_left_rect": dummy, "points_right_rect": dummy,
        "disparity_range": np.array([0.0, 40.0]), "left_name": np.asarray("view_00"),
        "right_name": np.asarray("view_01")})
    dio.write_npz(folder / "cameras.npz", "cameras",
                  cameras_to_arrays(["view_00", "view_01"], [left, right]))
    return folder


def dem(folder: Path, out: Path, *options: str):
    return CliRunner().invoke(cli, [
        "-q", "dem", "--disparity", str(folder / "disparity.tif"), "--rectify",
        str(folder / "rectify.npz"), "--cameras", str(folder / "cameras.npz"), "--out",
        str(out), "--interpolated-mask", str(out.with_name("mask_" + out.name)),
        *map(str, options)])


def outputs(out: Path) -> tuple[np.ndarray, np.ndarray, dict, float]:
    raster = dio.read_raster(out)
    mask = dio.read_raster(out.with_name("mask_" + out.name)).data
    sidecar = json.loads(Path(f"{out}.json").read_text())
    return raster.data, mask, sidecar["summary"], raster.spacing[0]


@pytest.fixture(scope="module")
def untiled(pair, tmp_path_factory) -> dict:
    results = {}
    for target in ("view_00", "view_01"):
        out = tmp_path_factory.mktemp("untiled_dem") / "dem.tif"
        result = dem(pair, out, "--target", target)
        assert result.exit_code == 0, result.output
        results[target] = outputs(out)
    return results


def rmse(dem_m: np.ndarray, target: str) -> float:
    truth = truth_grid(nadir_camera() if target == "view_00" else nadir_camera(BASELINE))
    return float(np.sqrt(np.mean((dem_m - truth) ** 2)))


@pytest.mark.parametrize("target", ["view_00", "view_01"])
def test_tiled_dem_equals_untiled_when_the_coarse_solve_is_at_full_resolution(
        pair, untiled, tmp_path, target):
    out = tmp_path / "dem.tif"
    result = dem(pair, out, *TILE, "--target", target)
    assert result.exit_code == 0, result.output
    heights, mask, summary, spacing = outputs(out)
    ref_heights, ref_mask, ref_summary, ref_spacing = untiled[target]
    assert summary["tiling"]["tiles"] == 9 and summary["coarse_factor"] == 1
    assert np.isfinite(heights).all()
    assert np.abs(heights - ref_heights).max() < 1e-5  # metres
    assert np.array_equal(mask, ref_mask)  # the same cells measured: same completeness
    assert 0.3 < mask.mean() < 0.5  # the gaps were filled, not dropped
    assert summary["measured_fraction"] == pytest.approx(ref_summary["measured_fraction"])
    assert summary["outliers_removed"] == ref_summary["outliers_removed"]
    assert summary["outliers_removed"] > 50  # the 1 % wild disparities
    assert spacing == pytest.approx(ref_spacing, rel=1e-5)  # median depth from histograms
    assert rmse(heights, target) == pytest.approx(rmse(ref_heights, target), abs=1e-6)
    assert not tiling.work_folder(out).exists() and not Path(f"{out}.lock").exists()


@pytest.mark.parametrize("target", ["view_00", "view_01"])
def test_a_decimated_coarse_solve_stays_within_a_centimetre(pair, untiled, tmp_path,
                                                           monkeypatch, target):
    monkeypatch.setattr(tiled_dem, "COARSE_MAX_CELLS", 600)  # 96² → 24² cells: f = 4
    out = tmp_path / "dem.tif"
    result = dem(pair, out, *TILE, "--tile-overlap", "16", "--target", target)
    assert result.exit_code == 0, result.output
    heights, mask, summary, _ = outputs(out)
    ref_heights, ref_mask, _, _ = untiled[target]
    assert summary["coarse_factor"] == 4
    difference = np.abs(heights - ref_heights)
    assert np.mean(difference < 0.01) >= 0.995  # 0.01 m = 0.02 GSD
    assert difference.max() < 0.02
    assert np.array_equal(mask, ref_mask)
    assert rmse(heights, target) == pytest.approx(rmse(ref_heights, target), abs=0.003)


def test_without_the_schwarz_sweep_the_decimated_solve_is_worse(pair, untiled, tmp_path,
                                                                monkeypatch):
    """The sweep is what brings the decimated solve within tolerance (not the margin)."""
    monkeypatch.setattr(tiled_dem, "COARSE_MAX_CELLS", 600)
    monkeypatch.setattr(tiled_dem, "SWEEPS", 0)
    out = tmp_path / "dem.tif"
    assert dem(pair, out, *TILE, "--tile-overlap", "16").exit_code == 0
    difference = np.abs(outputs(out)[0] - untiled["view_00"][0])
    assert difference.max() > 0.015


def test_a_failed_tile_then_a_resumed_run_writes_the_same_bytes(pair, tmp_path, monkeypatch):
    out = tmp_path / "run" / "dem.tif"
    mask = out.with_name("mask_dem.tif")
    assert dem(pair, out, *TILE).exit_code == 0
    reference = out.read_bytes(), mask.read_bytes()
    for path in (out, mask, Path(f"{out}.json")):
        path.unlink()
    original = tiled_dem.DemTileJob.compute
    calls: list[tuple[str, int]] = []

    def failing(self, tile, threads):
        calls.append((self.step, tile.index))
        if self.step == "fill" and tile.index == 4:
            raise RuntimeError("worker lost")
        return original(self, tile, threads)

    monkeypatch.setattr(tiled_dem.DemTileJob, "compute", failing)
    result = dem(pair, out, *TILE)
    assert result.exit_code == 1
    assert "tile 4 (rows 32–64, columns 32–64) failed: worker lost" in result.output
    assert result.output.count("\n") == 1
    assert not out.exists() and not mask.exists() and not Path(f"{out}.json").exists()
    calls.clear()
    monkeypatch.setattr(tiled_dem.DemTileJob, "compute", lambda self, tile, threads: (
        calls.append((self.step, tile.index)), original(self, tile, threads))[1])
    result = dem(pair, out, *TILE)
    assert result.exit_code == 0, result.output
    assert calls == [("fill", i) for i in range(4, 9)]  # only the missing tiles
    assert (out.read_bytes(), mask.read_bytes()) == reference
    assert not tiling.work_folder(out).exists()


def test_dry_run_plans_and_writes_nothing(pair, tmp_path):
    out = tmp_path / "dem.tif"
    result = dem(pair, out, *TILE, "--dry-run")
    assert result.exit_code == 0, result.output
    assert "96×96 px in 9 tiles (3×3) of 32 px" in result.output
    assert "estimated peak memory per worker:" in result.output
    assert list(tmp_path.iterdir()) == []


def test_a_small_target_with_tile_options_runs_untiled(pair, untiled, tmp_path):
    out = tmp_path / "dem.tif"
    result = dem(pair, out, "--tile-size", "128")
    assert result.exit_code == 0, result.output
    heights, _, summary, _ = outputs(out)
    assert "tiling" not in summary
    assert np.array_equal(heights, untiled["view_00"][0])


@pytest.mark.parametrize("options, message", [
    (["--mask-band"], "--mask-band is not written in tiles: use --interpolated-mask"),
    (["--median", "9", "--tile-overlap", "2"],
     "--tile-overlap must be >= 4 px (half the --median window), got 2"),
])
def test_bad_tile_options_name_the_option(pair, tmp_path, options, message):
    out = tmp_path / "dem.tif"
    result = dem(pair, out, *TILE, *options)
    assert result.exit_code == 1
    assert message in result.output and result.output.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_tile_options_on_a_route_not_tiled_are_refused(pair, tmp_path):
    reference = tmp_path / "reference.tif"
    dio.write_raster(reference, truth_grid(nadir_camera()), tags={"frame": "image:view_00"})
    out = tmp_path / "dem.tif"
    result = CliRunner().invoke(cli, [
        "-q", "dem", "--disparity", str(pair / "disparity.tif"), "--rectify",
        str(pair / "rectify.npz"), "--reference", str(reference), "--out", str(out), *TILE])
    assert result.exit_code == 1
    assert "only the calibrated disparity route (--disparity with --cameras) runs in tiles" \
        in result.output
    assert not out.exists()


def test_a_disparity_mostly_outside_the_range_is_refused_in_tiles(pair, tmp_path):
    folder = tmp_path / "pair"
    folder.mkdir()
    for name in ("rectify.npz", "cameras.npz"):
        (folder / name).write_bytes((pair / name).read_bytes())
    disparity = dio.read_raster(pair / "disparity.tif").data * 1000.0
    dio.write_raster(folder / "disparity.tif", disparity, tags={"frame": "image:view_00_rect"})
    out = tmp_path / "dem.tif"
    result = dem(folder, out, *TILE)
    assert result.exit_code == 1
    assert "of the disparities lie outside" in result.output
    assert "disparity.tif" in result.output and result.output.count("\n") == 1
    assert not out.exists() and not tiling.work_folder(out).exists()


def test_a_disparity_of_another_canvas_is_refused_in_tiles(pair, tmp_path):
    folder = tmp_path / "pair"
    folder.mkdir()
    for name in ("rectify.npz", "cameras.npz"):
        (folder / name).write_bytes((pair / name).read_bytes())
    dio.write_raster(folder / "disparity.tif", np.ones((50, 60), np.float32),
                     tags={"frame": "image:view_00_rect"})
    result = dem(folder, tmp_path / "dem.tif", *TILE)
    assert result.exit_code == 1
    assert "disparity is 60×50 px but" in result.output
    assert "rectified canvas" in result.output


def test_histogram_median_is_within_its_bin():
    rng = np.random.default_rng(1)
    values = rng.lognormal(-2.0, 1.0, 100_001)
    halves = [dem_grids.log_histogram(values[:40_000], 1000),
              dem_grids.log_histogram(values[40_000:], 1000)]
    median = dem_grids.histogram_median(halves, 1000)
    assert median == pytest.approx(np.median(values), rel=2.4e-3)
    assert dem_grids.histogram_median([{}], 1000) is None


def test_coarse_factor_keeps_the_coarse_grid_within_its_budget():
    assert tiled_dem.coarse_factor(1000, 1000, 1024 * 1024) == 1
    assert tiled_dem.coarse_factor(20_000, 50_000, 1024 * 1024) == 31
    assert 646 * 1613 <= 1024 * 1024 < 667 * 1667  # the grids at f = 31 and f = 30


@pytest.mark.slow
def test_tiled_dem_on_the_small_synthetic_scene(small_scene_dir, tmp_path):
    """rectify → sgm → dem on the small scene: 9 tiles of 64 px; as accurate as untiled."""
    from demtool.dem.params import DemParams
    from demtool.dem.run import run_dem
    from demtool.rectify.run import run_rectify
    from demtool.sgm.run import run_sgm

    stereo = tmp_path / "stereo"
    run_rectify(small_scene_dir / "view_00.tif", small_scene_dir / "view_01.tif", stereo)
    run_sgm(stereo / "left_rect.tif", stereo / "right_rect.tif", stereo / "disparity.tif",
            rectify=stereo / "rectify.npz")
    truth = dio.read_raster(small_scene_dir / "truth_dem_target.tif").data
    results = {}
    for name, tile_size in (("untiled", 0), ("tiled", 64)):
        out = tmp_path / f"{name}.tif"
        summary = run_dem(out, DemParams(tile_size=tile_size),
                          disparity_path=stereo / "disparity.tif",
                          rectify_path=stereo / "rectify.npz",
                          cameras_path=small_scene_dir / "cameras.npz",
                          mask_path=tmp_path / f"mask_{name}.tif")
        results[name] = (dio.read_raster(out), dio.read_raster(tmp_path / f"mask_{name}.tif"),
                         summary)
    (untiled, untiled_mask, _), (tiled, tiled_mask, summary) = results.values()
    assert summary["tiling"]["tiles"] == 9
    difference = np.abs(tiled.data - untiled.data)
    assert np.mean(difference < 0.01) >= 0.995 and difference.max() < 0.02  # metres
    assert np.array_equal(tiled_mask.data, untiled_mask.data)
    assert tiled.spacing[0] == pytest.approx(untiled.spacing[0], rel=1e-5)

    def nmad_error(heights: np.ndarray) -> float:
        error = heights - truth
        return float(1.4826 * np.median(np.abs(error - np.median(error))))

    assert nmad_error(untiled.data) < 0.5  # metres: a DEM of the scene, not noise
    assert nmad_error(tiled.data) == pytest.approx(nmad_error(untiled.data), abs=1e-3)


def test_a_locked_output_is_refused(pair, tmp_path):
    out = tmp_path / "dem.tif"
    with tiling.output_lock(out):
        result = dem(pair, out, *TILE)
    assert result.exit_code == 1
    assert f"{out}: another demtool run is writing this output" in result.output
    assert not out.exists() and result.output.count("\n") == 1


def test_an_unreachable_scheduler_names_the_option(pair, tmp_path, monkeypatch):
    monkeypatch.setattr("demtool.tiling.distributed.CONNECT_TIMEOUT", "1s")
    out = tmp_path / "dem.tif"
    result = dem(pair, out, *TILE, "--scheduler", "tcp://127.0.0.1:9")
    assert result.exit_code == 1
    assert "--scheduler tcp://127.0.0.1:9: cannot connect to the Dask scheduler" in result.output
    assert not out.exists()


@pytest.mark.slow
def test_two_local_dask_workers_give_the_same_dem(pair, tmp_path):
    one, two = tmp_path / "one.tif", tmp_path / "two.tif"
    assert dem(pair, one, *TILE).exit_code == 0
    result = dem(pair, two, *TILE, "--workers", "2")
    assert result.exit_code == 0, result.output
    assert np.array_equal(outputs(one)[0], outputs(two)[0])
    assert np.array_equal(outputs(one)[1], outputs(two)[1])
    assert not tiling.work_folder(two).exists()


def test_the_median_filter_in_tiles_matches_untiled(pair, tmp_path, monkeypatch):
    reference = tmp_path / "untiled.tif"
    assert dem(pair, reference, "--median", "5").exit_code == 0
    expected = outputs(reference)[0]
    full, decimated = tmp_path / "full.tif", tmp_path / "decimated.tif"
    assert dem(pair, full, *TILE, "--median", "5").exit_code == 0
    assert np.abs(outputs(full)[0] - expected).max() < 1e-5
    monkeypatch.setattr(tiled_dem, "COARSE_MAX_CELLS", 600)  # f = 4: a sweep, then the median
    result = dem(pair, decimated, *TILE, "--median", "5", "--tile-overlap", "16")
    assert result.exit_code == 0, result.output
    difference = np.abs(outputs(decimated)[0] - expected)
    assert np.mean(difference < 0.01) >= 0.995 and difference.max() < 0.02


def test_a_disparity_of_another_pair_is_refused_in_tiles(pair, tmp_path):
    folder = tmp_path / "pair"
    folder.mkdir()
    for name in ("rectify.npz", "cameras.npz"):
        (folder / name).write_bytes((pair / name).read_bytes())
    disparity = dio.read_raster(pair / "disparity.tif").data
    dio.write_raster(folder / "disparity.tif", disparity, tags={"frame": "image:other_rect"})
    result = dem(folder, tmp_path / "dem.tif", *TILE)
    assert result.exit_code == 1
    assert "disparity in frame image:other_rect, but" in result.output
    assert result.output.count("\n") == 1 and not (tmp_path / "dem.tif").exists()
