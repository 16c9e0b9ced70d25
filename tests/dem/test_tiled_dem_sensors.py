"""`dem --disparity D --mapprojected LEFT RIGHT` in tiles (demtool.dem.tiled_map) on a small
`synth --sensor linescan` scene: the tiled DEM, mask and ray-gap raster against the
untiled ones (issue 15: heights within 0.01 m on ≥ 99.5 % of cells, same completeness,
as accurate against truth_dem_map.tif), resumable after a failed tile (byte-identical),
--workers 2 gives the same DEM; the options it refuses."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.linescan import on_truth, synth_ortho_pair

SIZE = 192  # cells; the orthoimages' grid
TILE = 64  # ≥ 9 tiles of the disparity grid, ≥ 4 of the output grid


def invoke(*args):
    return CliRunner().invoke(cli, [*map(str, args)])


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    work = tmp_path_factory.mktemp("tiled_dem_map")
    scene, _, left, right = synth_ortho_pair(work, SIZE)
    disparity = work / "disparity.tif"
    result = invoke("sgm", left, right, "--out", disparity)
    assert result.exit_code == 0, result.output
    outputs = {}
    for name, extra in (("untiled", ()), ("tiled", ("--tile-size", TILE))):
        paths = {k: work / f"{name}_{k}.tif" for k in ("dem", "mask", "error")}
        result = invoke("dem", "--disparity", disparity, "--mapprojected", left, right,
                        "--error-out", paths["error"], "--interpolated-mask", paths["mask"],
                        "--out", paths["dem"], *extra)
        assert result.exit_code == 0, result.output
        outputs[name] = paths
    return {"work": work, "scene": scene, "left": left, "right": right,
            "disparity": disparity, **outputs}


def read(path):
    return dio.read_raster(path)


def test_tiled_map_dem_matches_the_untiled_one(pair):
    untiled, tiled = read(pair["untiled"]["dem"]), read(pair["tiled"]["dem"])
    assert tiled.data.shape == untiled.data.shape
    assert tiled.transform == untiled.transform
    assert tiled.crs == untiled.crs
    a, b = untiled.data.astype(np.float64), tiled.data.astype(np.float64)
    assert np.array_equal(np.isfinite(a), np.isfinite(b))  # same completeness
    both = np.isfinite(a)
    assert both.sum() > 0.5 * a.size
    close = np.abs(a - b)[both] <= 0.01
    assert close.mean() >= 0.995, close.mean()
    sidecar = json.loads(pair["tiled"]["dem"].with_suffix(".tif.json").read_text())
    assert sidecar["summary"]["tiling"]["tiles"] >= 4
    assert sidecar["summary"]["route"] == "disparity-mapprojected"
    plain = json.loads(pair["untiled"]["dem"].with_suffix(".tif.json").read_text())
    for key in ("points", "measured_cells", "filled_cells", "overlap_cells"):
        assert abs(sidecar["summary"][key] - plain["summary"][key]) <= max(
            2, 0.001 * plain["summary"][key]), key
    assert sidecar["summary"]["max_ray_gap_m"] == pytest.approx(
        plain["summary"]["max_ray_gap_m"], rel=2e-3)


def test_tiled_mask_and_ray_gaps_match_the_untiled_ones(pair):
    for key, tolerance in (("mask", 0.0), ("error", 1e-4)):
        a = read(pair["untiled"][key]).data.astype(np.float64)
        b = read(pair["tiled"][key]).data.astype(np.float64)
        assert a.shape == b.shape
        same_nan = np.isnan(a) == np.isnan(b)
        assert same_nan.mean() >= 0.999, key
        both = ~np.isnan(a) & ~np.isnan(b)
        assert (np.abs(a - b)[both] <= tolerance).mean() >= 0.999, key


def test_tiled_map_dem_is_as_accurate_against_truth(pair):
    truth = read(pair["scene"] / "truth_dem_map.tif")
    rmse = {}
    for name in ("untiled", "tiled"):
        diff = on_truth(pair[name]["dem"], truth) - truth.data
        ok = np.isfinite(diff)
        rmse[name] = float(np.sqrt(np.mean(diff[ok] ** 2)))
    gsd = abs(read(pair["left"]).transform.a)
    assert rmse["untiled"] < gsd  # the untiled route's own check (tests/cli/test_mapstereo)
    assert abs(rmse["tiled"] - rmse["untiled"]) <= 0.02 * gsd, rmse


def tiled_dem(pair, out, *extra):
    return invoke("-q", "dem", "--disparity", pair["disparity"], "--mapprojected",
                  pair["left"], pair["right"], "--out", out, "--tile-size", TILE, *extra)


def route_dem(scenes, route, out, *extra):
    """The tiled dem of ``route`` ("mapprojected" or "frame") written to ``out``."""
    if route == "mapprojected":
        return tiled_dem(scenes["pair"], out, *extra)
    frame = scenes["frame"]
    return invoke("-q", "dem", "--disparity", frame["disparity"], "--rectify",
                  frame["rectify"], "--out", out, "--tile-size", TILE, *extra)


@pytest.fixture(scope="module")
def scenes(pair, frame):
    return {"pair": pair, "frame": frame}


@pytest.mark.parametrize("route", ["mapprojected", "frame"])
def test_a_failed_tile_then_a_resumed_run_writes_the_same_bytes(scenes, route, tmp_path,
                                                                monkeypatch):
    from demtool import tiling
    from demtool.dem import tiled_map as dem_map

    out = tmp_path / "run" / "dem.tif"
    error, mask = out.with_name("error.tif"), out.with_name("mask.tif")
    extra = ("--error-out", error, "--interpolated-mask", mask)
    assert route_dem(scenes, route, out, *extra).exit_code == 0
    reference = out.read_bytes(), error.read_bytes(), mask.read_bytes()
    for path in (out, error, mask, out.with_suffix(".tif.json")):
        path.unlink()
    original = dem_map.MapDemTileJob.compute
    calls = []

    def failing(self, tile, threads):
        calls.append((self.step, tile.index))
        if self.step == "fill" and tile.index == 2:
            raise RuntimeError("worker lost")
        return original(self, tile, threads)

    monkeypatch.setattr(dem_map.MapDemTileJob, "compute", failing)
    result = route_dem(scenes, route, out, *extra)
    assert result.exit_code == 1
    assert "tile 2 (rows 0–64, columns 128–" in result.output
    assert "failed: worker lost" in result.output and result.output.count("\n") == 1
    assert not any(p.exists() for p in (out, error, mask, out.with_suffix(".tif.json")))
    fills = sum(step == "fill" for step, _ in calls)
    calls.clear()
    monkeypatch.setattr(dem_map.MapDemTileJob, "compute", lambda self, tile, threads: (
        calls.append((self.step, tile.index)), original(self, tile, threads))[1])
    result = route_dem(scenes, route, out, *extra)
    assert result.exit_code == 0, result.output
    assert fills == 3 and calls[0] == ("fill", 2)  # only the missing tiles, no points again
    assert all(step == "fill" for step, _ in calls)
    assert (out.read_bytes(), error.read_bytes(), mask.read_bytes()) == reference
    assert not tiling.work_folder(out).exists()


def test_a_decimated_coarse_solve_and_the_median_stay_within_a_centimetre(
        pair, tmp_path, monkeypatch):
    from demtool.dem import tiled as tiled_dem_module

    untiled = tmp_path / "untiled.tif"
    result = invoke("-q", "dem", "--disparity", pair["disparity"], "--mapprojected",
                    pair["left"], pair["right"], "--out", untiled, "--median", "5")
    assert result.exit_code == 0, result.output
    monkeypatch.setattr(tiled_dem_module, "COARSE_MAX_CELLS", 3000)  # 192² → 48²: f = 4
    out = tmp_path / "tiled.tif"
    result = tiled_dem(pair, out, "--median", "5")
    assert result.exit_code == 0, result.output
    assert json.loads(out.with_suffix(".tif.json").read_text())["summary"][
        "coarse_factor"] == 4
    a, b = read(untiled).data.astype(np.float64), read(out).data.astype(np.float64)
    assert np.array_equal(np.isfinite(a), np.isfinite(b))
    difference = np.abs(a - b)[np.isfinite(a)]
    assert np.mean(difference < 0.01) >= 0.995 and difference.max() < 0.05


@pytest.mark.slow
@pytest.mark.parametrize("route", ["mapprojected", "frame"])
def test_two_local_dask_workers_give_the_same_dem(scenes, route, tmp_path):
    from demtool import tiling

    out = tmp_path / "two.tif"
    result = route_dem(scenes, route, out, "--workers", "2")
    assert result.exit_code == 0, result.output
    reference = scenes["pair" if route == "mapprojected" else "frame"]["tiled"]["dem"]
    assert np.array_equal(read(out).data, read(reference).data, equal_nan=True)
    assert not tiling.work_folder(out).exists()


@pytest.mark.parametrize("options, message", [
    (("--mask-band",), "--mask-band is not written in tiles: use --interpolated-mask"),
    (("--median", "5", "--tile-overlap", "1"), "--tile-overlap must be >= 2 px")])
def test_options_the_tiled_route_refuses_name_the_option(pair, tmp_path, options, message):
    out = tmp_path / "dem.tif"
    result = tiled_dem(pair, out, *options)
    assert result.exit_code == 1
    assert message in result.output and result.output.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_a_disparity_off_the_left_grid_is_refused_in_tiles(pair, tmp_path):
    disparity = read(pair["disparity"])
    cropped = tmp_path / "cropped.tif"
    dio.write_raster(cropped, disparity.data[:-8], transform=disparity.transform,
                     crs=disparity.crs)
    out = tmp_path / "dem.tif"
    result = invoke("-q", "dem", "--disparity", cropped, "--mapprojected", pair["left"],
                    pair["right"], "--out", out, "--tile-size", TILE)
    assert result.exit_code == 1
    assert "disparity is not on the grid of the left orthoimage" in result.output
    assert result.output.count("\n") == 1 and not out.exists()


def test_a_grid_that_fits_in_one_tile_runs_untiled(pair, tmp_path):
    out = tmp_path / "dem.tif"
    result = invoke("-q", "dem", "--disparity", pair["disparity"], "--mapprojected",
                    pair["left"], pair["right"], "--out", out, "--tile-size", 512)
    assert result.exit_code == 0, result.output
    assert "tiling" not in json.loads(out.with_suffix(".tif.json").read_text())["summary"]
    assert np.array_equal(read(out).data, read(pair["untiled"]["dem"]).data, equal_nan=True)


# ------------------------------------------------- the calibrated rectified (frame) route
@pytest.fixture(scope="module")
def frame(tmp_path_factory):
    work = tmp_path_factory.mktemp("tiled_dem_frame")
    scene = work / "scene"
    result = invoke("synth", "--sensor", "frame", "--size", SIZE, "--image-size", SIZE,
                    "--out", scene)
    assert result.exit_code == 0, result.output
    meta = json.loads((scene / "scene.json").read_text())
    left, right = meta["target"], meta["partner"]
    rect = work / "rect"
    result = invoke("rectify", scene / f"{left}.tif", scene / f"{right}.tif",
                    "--sensor-left", scene / f"{left}.json", "--sensor-right",
                    scene / f"{right}.json", "--out", rect)
    assert result.exit_code == 0, result.output
    disparity = work / "disparity.tif"
    result = invoke("sgm", rect / "left_rect.tif", rect / "right_rect.tif", "--rectify",
                    rect / "rectify.npz", "--out", disparity)
    assert result.exit_code == 0, result.output
    outputs = {}
    for name, extra in (("untiled", ()), ("tiled", ("--tile-size", TILE))):
        paths = {k: work / f"{name}_{k}.tif" for k in ("dem", "mask", "error")}
        result = invoke("-q", "dem", "--disparity", disparity, "--rectify",
                        rect / "rectify.npz", "--error-out", paths["error"],
                        "--interpolated-mask", paths["mask"], "--out", paths["dem"], *extra)
        assert result.exit_code == 0, result.output
        outputs[name] = paths
    return {"work": work, "scene": scene, "rectify": rect / "rectify.npz",
            "disparity": disparity, **outputs}


def test_tiled_frame_dem_matches_the_untiled_one(frame):
    untiled, tiled = read(frame["untiled"]["dem"]), read(frame["tiled"]["dem"])
    assert tiled.data.shape == untiled.data.shape
    # The map's centre is a mean of unit vectors summed in another order: same to 1e-12.
    assert np.allclose(tuple(tiled.transform), tuple(untiled.transform), rtol=1e-12,
                       atol=1e-9)
    assert tiled.crs.to_dict().keys() == untiled.crs.to_dict().keys()
    for key, value in untiled.crs.to_dict().items():
        assert tiled.crs.to_dict()[key] == (pytest.approx(value, rel=1e-12, abs=1e-12)
                                            if isinstance(value, float) else value), key
    a, b = untiled.data.astype(np.float64), tiled.data.astype(np.float64)
    assert np.array_equal(np.isfinite(a), np.isfinite(b))  # same completeness
    assert np.isfinite(a).mean() > 0.9
    difference = np.abs(a - b)[np.isfinite(a)]
    assert np.mean(difference <= 0.01) >= 0.995 and difference.max() < 1e-4
    for key in ("mask", "error"):
        x = read(frame["untiled"][key]).data.astype(np.float64)
        y = read(frame["tiled"][key]).data.astype(np.float64)
        assert np.array_equal(np.isnan(x), np.isnan(y)), key
        assert np.nanmax(np.abs(x - y)) <= 1e-6, key
    summary = json.loads(frame["tiled"]["dem"].with_suffix(".tif.json").read_text())["summary"]
    plain = json.loads(frame["untiled"]["dem"].with_suffix(".tif.json").read_text())["summary"]
    assert summary["route"] == "disparity-sensors" and summary["tiling"]["tiles"] >= 4
    for key in ("points", "measured_cells", "filled_cells", "overlap_cells",
                "rejected_ray_gap", "behind_camera", "valid_disparities"):
        assert summary[key] == plain[key], key
    for key in ("gsd_m", "max_ray_gap_m", "median_ray_gap_m", "height_median_m"):
        assert summary[key] == pytest.approx(plain[key], rel=1e-9), key


def test_tiled_frame_dem_is_as_accurate_against_truth(frame):
    truth = read(frame["scene"] / "truth_dem_map.tif")
    rmse = {}
    for name in ("untiled", "tiled"):
        diff = on_truth(frame[name]["dem"], truth) - truth.data
        ok = np.isfinite(diff)
        assert ok.sum() > 0.5 * truth.data.size
        rmse[name] = float(np.sqrt(np.mean(diff[ok] ** 2)))
    gsd = abs(truth.transform.a)
    assert rmse["untiled"] < gsd
    assert abs(rmse["tiled"] - rmse["untiled"]) <= 0.02 * gsd, rmse


def test_a_disparity_of_another_canvas_is_refused_in_tiles(frame, tmp_path):
    disparity = read(frame["disparity"])
    cropped = tmp_path / "cropped.tif"
    dio.write_raster(cropped, disparity.data[:-8])
    out = tmp_path / "dem.tif"
    result = invoke("-q", "dem", "--disparity", cropped, "--rectify", frame["rectify"],
                    "--out", out, "--tile-size", TILE)
    assert result.exit_code == 1
    assert f"{cropped}: disparity is" in result.output and "rectified canvas" in result.output
    assert result.output.count("\n") == 1 and not out.exists()


def test_a_disparity_mostly_outside_the_range_is_refused_in_tiles(frame, tmp_path):
    disparity = read(frame["disparity"])
    shifted = tmp_path / "shifted.tif"
    dio.write_raster(shifted, disparity.data + 1000.0)
    out = tmp_path / "dem.tif"
    result = invoke("-q", "dem", "--disparity", shifted, "--rectify", frame["rectify"],
                    "--out", out, "--tile-size", TILE)
    assert result.exit_code == 1
    assert "of the disparities lie outside" in result.output
    assert result.output.count("\n") == 1 and not out.exists()


def test_streaming_median_is_numpys_median():
    from demtool.dem.tiled_map_run import streaming_median

    rng = np.random.default_rng(3)
    for size in (1, 2, 7, 10_000, 10_001):
        values = np.concatenate([rng.standard_cauchy(size), [np.nan]])  # heavy tails
        chunks = np.array_split(values, 5)
        expected = float(np.median(values[np.isfinite(values)]))
        # by histogram refinement (kept in memory up to 3 values), and kept in memory
        assert streaming_median(lambda c=chunks: iter(c), bins=16, collect=8,
                                in_memory=3) == expected
        assert streaming_median(lambda c=chunks: iter(c)) == expected
    ties = [np.full(100, 2.5), np.full(50, 1.0)]
    assert streaming_median(lambda: iter(ties), bins=4, collect=3, in_memory=0) == 2.5
    assert streaming_median(lambda: iter(ties)) == 2.5
    assert streaming_median(lambda: iter([np.array([np.nan])])) is None


@pytest.mark.parametrize("route", ["mapprojected", "frame"])
def test_dry_run_plans_the_points_pass_and_writes_nothing(scenes, route, tmp_path):
    out = tmp_path / "dem.tif"
    result = route_dem(scenes, route, out, "--dry-run")
    assert result.exit_code == 0, result.output
    assert " tiles (" in result.output and " of 64 px" in result.output, result.output
    assert "estimated peak memory per worker:" in result.output
    assert list(tmp_path.iterdir()) == []


def test_a_disparity_with_two_values_is_refused_in_tiles_leaving_nothing(pair, tmp_path):
    disparity = read(pair["disparity"])
    sparse = tmp_path / "inputs" / "sparse.tif"
    sparse.parent.mkdir()
    data = np.full(disparity.data.shape, np.nan, dtype=np.float32)
    data[5, 5:7] = disparity.data[100, 100]
    dio.write_raster(sparse, data, transform=disparity.transform, crs=disparity.crs)
    out = tmp_path / "run" / "dem.tif"
    out.parent.mkdir()
    result = invoke("-q", "dem", "--disparity", sparse, "--mapprojected", pair["left"],
                    pair["right"], "--out", out, "--tile-size", TILE)
    assert result.exit_code == 1
    assert f"{sparse}: fewer than 3 valid disparities" in result.output
    assert result.output.count("\n") == 1
    assert list(out.parent.iterdir()) == []  # no output, no work folder


def test_two_tile_threads_stream_the_rasters_of_the_end_of_run_write(pair, tmp_path):
    """--workers 2 (tiles on threads) writes each finished fill tile while the others
    are computed (stream_outputs): the DEM, mask and ray-gap rasters of the one-worker
    run's end-of-run write (values, grid and tags but the parameters')."""
    out = tmp_path / "dem.tif"
    paths = {"dem": out, "mask": tmp_path / "mask.tif", "error": tmp_path / "error.tif"}
    result = tiled_dem(pair, out, "--workers", "2", "--error-out", paths["error"],
                       "--interpolated-mask", paths["mask"])
    assert result.exit_code == 0, result.output
    tiling = json.loads(out.with_suffix(".tif.json").read_text())["summary"]["tiling"]
    assert tiling["executor"] == "threads" and "write_after_tiles_s" in tiling  # streamed
    for key, path in paths.items():
        one, two = read(pair["tiled"][key]), read(path)
        assert np.array_equal(one.data, two.data, equal_nan=True), key
        assert one.transform == two.transform and one.crs == two.crs
        assert ({k: v for k, v in one.tags.items() if k != "demtool_params"}
                == {k: v for k, v in two.tags.items() if k != "demtool_params"})


def test_stored_points_decode_a_chosen_subset_as_the_whole():
    from demtool.dem.tiled_map import point_count, point_fields, split64, stored_points

    layout = point_fields(True)  # height, gap, range_left, x, y
    assert "lon" not in layout and point_fields(True, False) == ("height", "gap", "x", "y")
    rng = np.random.default_rng(3)
    values = rng.normal(1e6, 1e3, (len(layout), 9, 7))
    values[:, rng.random((9, 7)) < 0.3] = np.nan  # cells without a point
    stored = split64(values).transpose(1, 0, 2, 3).reshape(-1, 9, 7)
    whole = stored_points(stored, layout, layout=layout)
    assert point_count(stored, layout) == whole[0].size
    chosen = np.array([0, 3, 4, whole[0].size - 1])
    part = stored_points(stored, ("y", "height"), chosen, layout)
    assert np.array_equal(part[0], whole[-1][chosen])
    assert np.array_equal(part[1], whole[0][chosen])
    ok = np.isfinite(values[0])
    np.testing.assert_allclose(whole[0], values[0][ok], rtol=1e-13)  # split64: ~1e-14


def test_points_held_in_the_process_are_the_cached_points_decoded(tmp_path, monkeypatch):
    """What a points tile's later passes take from memory (the tile computed in this
    process) is bit for bit what they would decode from its cached file, the chosen
    subsets and the count too; past HELD_POINTS_MAX points the cache is read."""
    from demtool.dem import tiled_map
    from demtool.dem.tiled_map import (
        hold_points,
        point_count,
        point_fields,
        release_points,
        split64,
        stored_points,
        tile_point_count,
        tile_points,
    )
    from demtool.tiling import Tile, TileCache

    layout = point_fields(True, False)
    rng = np.random.default_rng(5)
    cache = TileCache(tmp_path / "points")
    tiles = [Tile(i, (0, 9, 0, 7), (0, 9, 0, 7)) for i in range(2)]
    stored = []
    for tile in tiles:
        values = rng.normal(1e5, 1e3, (len(layout), 9, 7))
        values[:, rng.random((9, 7)) < 0.3] = np.nan
        stored.append(split64(values).transpose(1, 0, 2, 3).reshape(-1, 9, 7))
        cache.store(tile, stored[-1], {})
    monkeypatch.setattr(tiled_map, "HELD_POINTS_MAX", point_count(stored[0], layout))
    folder = str(cache.folder)
    try:
        for tile, values in zip(tiles, stored, strict=True):
            hold_points(folder, tile, values, layout)  # the second one is past the cap
        assert (folder, 0) in tiled_map._HELD and (folder, 1) not in tiled_map._HELD
        for tile, values in zip(tiles, stored, strict=True):
            whole = stored_points(values, layout, layout=layout)
            assert tile_point_count(cache, tile, layout) == whole[0].size
            for got, want in zip(tile_points(cache, tile, layout, layout=layout), whole,
                                 strict=True):
                assert got.dtype == np.float64 and np.array_equal(got, want)
            chosen = np.array([0, 2, whole[0].size - 1])
            got = tile_points(cache, tile, ("y", "gap"), chosen, layout)
            assert np.array_equal(got[0], whole[3][chosen])
            assert np.array_equal(got[1], whole[1][chosen])
    finally:
        release_points(folder)
    assert not any(key[0] == folder for key in tiled_map._HELD)


@pytest.mark.parametrize("height, width, tile_size", [
    (1999, 2102, 1024), (300, 200, 64), (5000, 700, 512), (40, 9000, 64), (100, 90, 1024)])
def test_points_tiles_are_whole_rows_of_whole_lattice_strips(height, width, tile_size):
    """The points pass's tiles partition the grid in row order; whole-width rows, equally
    tall (the last one shorter), a multiple of the lattice's strip once that tall, about
    tile_size² cells each; squares where one row is more than tile_size² cells."""
    from demtool.dem.tiled_map import points_tiling
    from demtool.mapproject.lattice import STRIP_ROWS
    from demtool.tiling import plan_tiles

    tiling = points_tiling(height, width, tile_size)
    covered = np.zeros((height, width), dtype=np.int64)
    for i, tile in enumerate(tiling.tiles):
        r0, r1, c0, c1 = tile.core
        assert tile.index == i and tile.outer == tile.core
        covered[r0:r1, c0:c1] += 1
    assert (covered == 1).all()
    if width > tile_size**2:
        assert tiling.tiles == plan_tiles(height, width, tile_size, overlap=0).tiles
        return
    rows = [t.core[1] - t.core[0] for t in tiling.tiles]
    assert all(t.core[2:] == (0, width) for t in tiling.tiles)
    assert len(set(rows[:-1])) <= 1 and rows[-1] <= rows[0]
    assert len(rows) == -(-height * width // tile_size**2) or rows[0] % STRIP_ROWS == 0
    if rows[0] >= STRIP_ROWS:
        assert rows[0] % STRIP_ROWS == 0 and (rows[0] - STRIP_ROWS) * width < tile_size**2
    else:
        assert rows[0] * width <= tile_size**2 or len(rows) == 1
