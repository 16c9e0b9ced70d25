"""Internal overviews built on the closed file through GDAL's C API, outside the GIL:
the same bytes as rasterio's in-place build, other threads running meanwhile, GDAL's
failures as one error naming the file."""

import threading
import time

import numpy as np
import pytest
import rasterio
from affine import Affine

from demtool import io as dio
from demtool.errors import OutputError
from demtool.io import layout, overviews
from tests.helpers.fuse import moon_crs


def _heights(shape=(1100, 900), seed=1):
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    values = (np.sin(cols / 40.0) * 50 + rows * 0.1).astype(np.float32)
    values += rng.normal(0, 0.5, shape).astype(np.float32)
    values[200:260, 300:420] = np.nan
    return values


def _write_both_ways(tmp_path, monkeypatch, write):
    """``write(path)`` with the C API (outside the GIL) and with rasterio in place."""
    assert overviews.gdal_c_api() is not None  # Linux and macOS wheels: reachable
    write(tmp_path / "outside.tif")
    monkeypatch.setattr(overviews, "gdal_c_api", lambda: None)
    write(tmp_path / "in_place.tif")
    monkeypatch.undo()
    return (tmp_path / "outside.tif").read_bytes(), (tmp_path / "in_place.tif").read_bytes()


def test_deflate_rasters_with_tags_and_bands_get_the_bytes_of_the_in_place_build(
        tmp_path, monkeypatch):
    crs, _ = moon_crs()
    heights = _heights()
    mask = (np.isfinite(heights) & (heights > 20)).astype(np.float32)

    def write(path):
        dio.write_raster(path, np.stack([heights, mask]), transform=Affine(2, 0, 0, 0, -2, 0),
                         crs=crs, tags={"demtool_stage": "dem", "gsd_m": 2.0},
                         band_names=["height", "interpolated"])

    outside, in_place = _write_both_ways(tmp_path, monkeypatch, write)
    assert outside == in_place
    with rasterio.open(tmp_path / "outside.tif") as src:
        assert src.overviews(1) == [2, 4, 8]
        assert src.tags(ns="rio_overview") == {"resampling": "average"}
        assert src.tags()["demtool_stage"] == "dem"
        assert src.descriptions == ("height", "interpolated")
        half = src.read(1, out_shape=(550, 450))
    blocks = heights.reshape(550, 2, 450, 2)
    count = np.isfinite(blocks).sum(axis=(1, 3))
    with np.errstate(invalid="ignore"):
        mean = np.where(count > 0, np.nansum(blocks, axis=(1, 3)) / np.maximum(count, 1),
                        np.nan)
    np.testing.assert_allclose(half, mean, rtol=1e-5, atol=1e-4)  # NaN where all NaN


def test_zstd_block_writer_gets_level_1_overviews_as_in_place(tmp_path, monkeypatch):
    """The reopened file does not know its ZSTD level: ZSTD_LEVEL_OVERVIEW gives it 1, as
    the open dataset's own level gave the in-place build (GDAL's default would be 9)."""
    crs, _ = moon_crs()
    heights = _heights(seed=2)

    def write(path):
        with dio.raster_writer(path, height=1100, width=900,
                               transform=Affine(1, 0, 5, 0, -1, 0), crs=crs) as writer:
            writer.write(heights[:600], 0, 0)
            writer.write(heights[600:], 600, 0)

    outside, in_place = _write_both_ways(tmp_path, monkeypatch, write)
    assert outside == in_place
    with rasterio.open(tmp_path / "outside.tif") as src:
        assert src.tags(ns="IMAGE_STRUCTURE")["COMPRESSION"] == "ZSTD"
        np.testing.assert_array_equal(src.read(1), heights)


def _spins_during(build) -> float:
    """Loop iterations per second of this thread while ``build()`` runs on another (from
    when that thread calls it to when it returns)."""
    span = {}

    def work():
        span["start"] = time.perf_counter()
        build()
        span["end"] = time.perf_counter()

    worker = threading.Thread(target=work)
    marks, spins = [], 0
    worker.start()
    while worker.is_alive():
        spins += 1
        if spins % 1000 == 0:
            marks.append(time.perf_counter())
    worker.join()
    inside = sum(span["start"] <= mark <= span["end"] for mark in marks)
    return 1000 * inside / (span["end"] - span["start"])


def test_other_threads_run_while_the_overviews_are_built(tmp_path):
    """rasterio's build_overviews holds the GIL for the whole build; the C API's does not:
    a Python loop on the calling thread keeps running (measured: ~100x more iterations)."""
    from rasterio.enums import Resampling

    values = np.random.default_rng(3).normal(size=(2048, 2048)).astype(np.float32)
    profile = {"driver": "GTiff", "dtype": "float32", "width": 2048, "height": 2048,
               "count": 1, "tiled": True, "blockxsize": 256, "blockysize": 256,
               "compress": "deflate", "zlevel": 1, "predictor": 3,
               "crs": moon_crs()[0], "transform": Affine(1, 0, 0, 0, -1, 2048)}
    for name in ("a.tif", "b.tif"):
        with rasterio.open(tmp_path / name, "w", **profile) as dst:
            dst.write(values, 1)
    with rasterio.open(tmp_path / "a.tif", "r+") as dst:
        held = _spins_during(lambda: dst.build_overviews([2, 4, 8], Resampling.average))
    free = _spins_during(lambda: overviews.build_overviews_of_file(
        tmp_path / "b.tif", [2, 4, 8], "average"))
    assert free > 10 * held
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        assert b.overviews(1) == [2, 4, 8]
        np.testing.assert_array_equal(a.read(1, out_shape=(512, 512)),
                                      b.read(1, out_shape=(512, 512)))


def test_gdal_failures_are_one_error_naming_the_file(tmp_path):
    from rasterio.errors import RasterioError

    with pytest.raises(RasterioError, match="missing.tif"):
        overviews.build_overviews_of_file(tmp_path / "missing.tif", [2], "average")


def test_a_failed_overview_build_leaves_no_output(tmp_path, monkeypatch):
    from rasterio.errors import RasterioError

    def failing(path, factors, resampling):
        raise RasterioError(f"{path}: No space left on device")

    monkeypatch.setattr(overviews, "build_overviews_of_file", failing)
    crs, _ = moon_crs()
    with pytest.raises(OutputError, match="dem.tif"):
        dio.write_raster(tmp_path / "dem.tif", _heights(), crs=crs,
                         transform=Affine(1, 0, 5, 0, -1, 0))
    assert list(tmp_path.iterdir()) == []


def test_small_rasters_get_no_overviews_either_way(tmp_path):
    crs, _ = moon_crs()
    path = dio.write_raster(tmp_path / "small.tif", _heights((300, 500)), crs=crs,
                            transform=Affine(1, 0, 5, 0, -1, 0))
    with rasterio.open(path) as src:
        assert src.overviews(1) == [] and src.tags(ns="rio_overview") == {}
    assert layout.overview_factors(300, 500) == []
