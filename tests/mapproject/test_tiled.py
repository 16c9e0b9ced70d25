"""``demtool mapproject`` on the tile engine (demtool/mapproject/tiled.py): the engine's
orthoimage and angles equal the in-process loop's, a failed tile is reported and the run
resumes byte-identical, the dry run writes nothing, a locked output is refused."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool import tiling
from demtool.cli import cli
from demtool.mapproject.core import ortho_grid
from demtool.mapproject.tiled import engine_tile_size
from demtool.maps import snap_grid
from tests.helpers.linescan import MOON, linescan_sensor, write_scene, write_truth_dem


def invoke(*args):
    return CliRunner().invoke(cli, ["mapproject", *map(str, args)])


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A rolled line-scan view of the analytic terrain, its ISD and the truth DEM."""
    folder = tmp_path_factory.mktemp("linescan_tiled")
    sensor = linescan_sensor(lines=260, samples=180, roll_deg=15.0)
    image, isd = write_scene(folder, sensor)
    grid = ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 1.0)
    dem = write_truth_dem(folder / "truth_dem_map.tif", grid)
    return {"folder": folder, "image": image, "isd": isd, "dem": dem, "grid": grid}


@pytest.fixture(scope="module")
def in_process(scene, tmp_path_factory):
    """The default path's orthoimage and angles, map tiles of 64 cells."""
    folder = tmp_path_factory.mktemp("in_process")
    out, angles = folder / "ortho.tif", folder / "angles.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--dem", scene["dem"], "--out",
                    out, "--angles-out", angles, "--tile-size", 64)
    assert result.exit_code == 0, result.output
    return out, angles


def engine_run(scene, out, *extra, angles=None):
    more = ["--angles-out", angles] if angles is not None else []
    return invoke(scene["image"], "--sensor", scene["isd"], "--dem", scene["dem"], "--out",
                  out, "--tile-size", 64, *more, *extra)


def test_engine_tile_size_keeps_the_in_process_loop_by_default():
    def params(**kw):
        return SimpleNamespace(**{"tile_size": 64, "workers": 0, "scheduler": None,
                                  "dry_run": False, **kw})

    assert engine_tile_size((300, 200), params()) == 0  # the default: in process
    assert engine_tile_size((300, 200), params(workers=1)) == 64
    assert engine_tile_size((300, 200), params(workers=2)) == 64
    assert engine_tile_size((60, 50), params(workers=2)) == 0  # one tile: in process
    assert engine_tile_size((60, 50), params(dry_run=True)) == 64
    assert engine_tile_size((60, 50), params(scheduler="tcp://h:1")) == 64


def test_engine_equals_the_in_process_loop(scene, in_process, tmp_path):
    out, angles = tmp_path / "ortho.tif", tmp_path / "angles.tif"
    result = engine_run(scene, out, "--workers", 1, angles=angles)
    assert result.exit_code == 0, result.output
    want, got = dio.read_raster(in_process[0]), dio.read_raster(out)
    assert got.data.shape == want.data.shape and got.data.shape[0] > 128  # several tiles
    assert np.isfinite(got.data).mean() > 0.9
    np.testing.assert_array_equal(got.data, want.data)  # NaNs at the same cells too
    assert got.transform == want.transform and got.crs == want.crs
    for band in (1, 2, 3):
        np.testing.assert_array_equal(dio.read_raster(angles, band=band).data,
                                      dio.read_raster(in_process[1], band=band).data)
    for key in ("mapproject_sensor", "mapproject_surface", "mapproject_dem", "body", "frame"):
        assert got.tags[key] == want.tags[key]
    import rasterio

    with rasterio.open(angles) as dataset:
        assert dataset.count == 3
        assert dataset.descriptions == ("incidence_deg", "emission_deg", "phase_deg")
    for path, reference in ((out, in_process[0]), (angles, in_process[1])):
        with rasterio.open(path) as dataset, rasterio.open(reference) as untiled:
            assert dataset.compression == untiled.compression  # the untiled path's ZSTD
    summary = json.loads(Path(f"{out}.json").read_text())["summary"]
    base = json.loads(Path(f"{in_process[0]}.json").read_text())["summary"]
    rows, cols = got.data.shape
    assert summary["tiling"]["tiles"] == -(-rows // 64) * -(-cols // 64)
    assert summary["tiling"]["margins_top_bottom_left_right"] == [0, 0, 0, 0]
    for key in ("valid_fraction", "lattice_steps", "max_interpolation_error_px",
                "tiles_off_image", "width", "height"):
        assert summary[key] == base[key], key
    assert not tiling.work_folder(out).exists() and not Path(f"{out}.lock").exists()


def test_two_workers_on_threads_equal_the_in_process_loop(scene, in_process, tmp_path):
    """--workers 2: the map tiles on two threads of the command's process
    (demtool.tiling.local_threads), the orthoimage equal to the bit."""
    out = tmp_path / "ortho.tif"
    result = engine_run(scene, out, "--workers", 2)
    assert result.exit_code == 0, result.output
    found, expected = dio.read_raster(out).data, dio.read_raster(in_process[0]).data
    np.testing.assert_array_equal(found.view(np.uint32), expected.view(np.uint32))
    tiles = json.loads(Path(f"{out}.json").read_text())["summary"]["tiling"]
    assert tiles["executor"] == "threads"


def test_failed_tile_is_reported_then_the_run_resumes_byte_identical(scene, tmp_path,
                                                                     monkeypatch):
    from demtool.mapproject import tiled as tiled_mp

    out, angles = tmp_path / "run" / "ortho.tif", tmp_path / "run" / "angles.tif"
    assert engine_run(scene, out, "--workers", 1, angles=angles).exit_code == 0
    reference = out.read_bytes(), angles.read_bytes()
    for path in (out, angles, Path(f"{out}.json")):
        path.unlink()
    original = tiled_mp.MapprojectTileJob.compute
    calls: list[int] = []

    def failing(self, tile, threads):
        calls.append(tile.index)
        if tile.index == 4:
            raise RuntimeError("worker lost")
        return original(self, tile, threads)

    monkeypatch.setattr(tiled_mp.MapprojectTileJob, "compute", failing)
    result = engine_run(scene, out, "--workers", 1, angles=angles)
    assert result.exit_code == 1
    assert "mapproject: tile 4 (rows 64–128, columns" in result.output
    assert "failed: worker lost" in result.output and "4 finished tiles are cached" \
        in result.output
    assert not out.exists() and not angles.exists() and not Path(f"{out}.json").exists()
    assert len(list(tiling.work_folder(out).glob("*/tile_*.npy"))) == 4
    calls.clear()
    monkeypatch.setattr(tiled_mp.MapprojectTileJob, "compute", lambda self, tile, threads: (
        calls.append(tile.index), original(self, tile, threads))[1])
    result = engine_run(scene, out, "--workers", 1, angles=angles)
    assert result.exit_code == 0, result.output
    assert calls and calls[0] == 4 and 3 not in calls  # only the missing tiles
    assert (out.read_bytes(), angles.read_bytes()) == reference
    assert not tiling.work_folder(out).exists()


def test_dry_run_prints_the_plan_and_writes_nothing(scene, tmp_path):
    out = tmp_path / "ortho.tif"
    result = engine_run(scene, out, "--dry-run")
    assert result.exit_code == 0, result.output
    assert "tiles" in result.output and "of 64 px, margins top 0 bottom 0" in result.output
    assert "estimated peak memory per worker:" in result.output
    assert "calibration tile (the largest):" in result.output
    assert list(tmp_path.iterdir()) == []


def test_a_locked_output_is_refused(scene, tmp_path):
    out = tmp_path / "ortho.tif"
    with tiling.output_lock(out):
        result = engine_run(scene, out, "--workers", 1)
    assert result.exit_code == 1
    lines = [ln for ln in result.output.splitlines() if ln.startswith("Error")]
    assert len(lines) == 1 and f"{out}: another demtool run is writing this output" in lines[0]
    assert not out.exists()


def tiling_work_folder(out):
    from demtool.tiling import work_folder

    return work_folder(out)


def test_no_cell_seeing_the_image_is_refused_on_the_engine(scene, tmp_path):
    """Bounds far from the footprint: refused before any tile (issue 31: the grid is checked
    against the image's footprint first, naming --bounds); nothing is written."""
    out = tmp_path / "ortho.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--out", out,
                    "--gsd", 2.0, "--bounds", 40, 40, 40.01, 40.01, "--tile-size", 64,
                    "--workers", 1)
    assert result.exit_code == 1
    lines = [ln for ln in result.output.splitlines() if ln.startswith("Error")]
    assert len(lines) == 1 and "--bounds: lon 40…40.01, lat 40…40.01 does not overlap the " \
        "image's footprint" in lines[0], result.output
    assert not tiling_work_folder(out).exists()
    assert not out.exists() and not Path(f"{out}.json").exists()
