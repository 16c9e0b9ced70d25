"""Rasters written tiled with internal overviews (resampling by kind), or as COG."""

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.io.layout import (
    current_layout,
    overview_factors,
    overview_resampling,
    raster_layout,
)
from tests.helpers.fuse import moon_crs


def test_overview_factors_go_down_to_one_block_and_skip_small_rasters():
    assert overview_factors(512, 300) == []
    assert overview_factors(600, 100) == [2, 4]  # 300 > 256, 150 fits a block
    assert overview_factors(4096, 4096) == [2, 4, 8, 16]
    assert overview_factors(20000, 20000)[-1] == 128  # 157 px a side at the top


def test_overview_resampling_by_band_kind():
    assert overview_resampling(["height"]) == "average"
    assert overview_resampling(None) == "average"
    assert overview_resampling(["interpolated"]) == "nearest"
    assert overview_resampling(["count"]) == "nearest"
    assert overview_resampling(["height", "interpolated"]) == "average"  # heights first


def _dem(shape=(600, 640)):
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    dem = 0.5 * rows + 0.25 * cols + np.sin(cols / 7.0).astype(np.float32)
    dem[10:13, 20:23] = np.nan
    dem[100:140, 200:240] = np.nan
    return dem


def test_heights_get_averaged_overviews_that_skip_nan(tmp_path):
    dem = _dem()
    crs, _ = moon_crs()
    transform = Affine(2.0, 0, 0, 0, -2.0, 0)
    path = dio.write_raster(tmp_path / "dem.tif", dem, transform=transform, crs=crs,
                            tags={"demtool_stage": "dem", "gsd_m": 2.0},
                            band_names=["height"])
    with rasterio.open(path) as src:
        assert src.overviews(1) == [2, 4]
        assert src.block_shapes == [(256, 256)]
        assert src.tags(ns="rio_overview") == {"resampling": "average"}
        assert src.tags()["demtool_stage"] == "dem" and src.descriptions == ("height",)
        half = src.read(1, out_shape=(300, 320))
    back = dio.read_raster(path)  # full resolution: as before, bit for bit
    np.testing.assert_array_equal(back.data, dem)
    assert back.transform == transform and back.crs == crs
    blocks = dem.reshape(300, 2, 320, 2)
    count = np.isfinite(blocks).sum(axis=(1, 3))
    with np.errstate(invalid="ignore"):  # all-NaN blocks stay NaN
        expected = np.nansum(blocks, axis=(1, 3)) / np.where(count, count, np.nan)
    np.testing.assert_allclose(half, expected, rtol=1e-6, equal_nan=True)
    assert np.isnan(half[60, 110]) and np.isfinite(half[6, 11])  # hole, part-hole


def test_masks_and_counts_get_nearest_overviews(tmp_path):
    mask = (np.indices((600, 600)).sum(axis=0) % 3 == 0).astype(np.float32)
    path = dio.write_raster(tmp_path / "mask.tif", mask, band_names=["interpolated"])
    with rasterio.open(path) as src:
        assert src.tags(ns="rio_overview") == {"resampling": "nearest"}
        assert set(np.unique(src.read(1, out_shape=(150, 150)))) == {0.0, 1.0}


def test_block_writer_gets_overviews_too(tmp_path):
    dem = _dem()
    with dio.raster_writer(tmp_path / "big.tif", height=600, width=640,
                           band_names=["ortho"]) as writer:
        writer.write(dem[:300], 0, 0)
        writer.write(dem[300:], 300, 0)
    with rasterio.open(tmp_path / "big.tif") as src:
        assert src.overviews(1) == [2, 4]
        np.testing.assert_array_equal(src.read(1), dem)


def test_cog_layout_is_a_valid_cog_with_tags_and_no_leftovers(tmp_path):
    dem = _dem()
    with raster_layout("cog"):
        assert current_layout() == "cog"
        dio.write_raster(tmp_path / "dem.tif", dem, tags={"demtool_stage": "dem"},
                         band_names=["height"])
    assert current_layout() == "gtiff"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.tif"]
    with rasterio.open(tmp_path / "dem.tif") as src:
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert src.overviews(1) == [2]  # COG: down to one 512-px block
        assert src.tags()["demtool_stage"] == "dem" and src.descriptions == ("height",)
        np.testing.assert_array_equal(src.read(1), dem)
    with pytest.raises(ValueError, match="unknown raster layout"):
        with raster_layout("png"):
            pass


def test_cog_option_of_the_command_line_applies_to_that_run_only(tmp_path):
    from tests.helpers.fuse import write_dem

    write_dem(tmp_path / "a.tif", (0, 300, 0, 600))
    result = CliRunner().invoke(cli, ["-q", "--cog", "fuse", str(tmp_path / "a.tif"),
                                      "--out", str(tmp_path / "fused.tif")])
    assert result.exit_code == 0, result.output
    assert current_layout() == "gtiff"
    with rasterio.open(tmp_path / "fused.tif") as src:
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
    with rasterio.open(tmp_path / "fused_count.tif") as src:
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert set(np.unique(src.read(1, out_shape=(150, 300)))) <= {0.0, 1.0}


def test_large_rasters_are_compressed_on_every_core_with_the_same_bytes(tmp_path,
                                                                          monkeypatch):
    """A raster of at least THREADED_COMPRESSION_PIXELS is created with GDAL's compression
    threads (its blocks and overviews compressed off the writing thread): the file's
    bytes are those written on one thread, and GDAL's configuration is back after it."""
    import contextlib

    from rasterio._env import get_gdal_config

    from demtool.io import layout

    rng = np.random.default_rng(3)
    values = rng.normal(0.5, 0.1, (700, 900)).astype(np.float32)  # > 512 px: overviews
    values[100:180, 200:260] = np.nan
    seen = []
    opened = rasterio.open

    def spying_open(*args, **kwargs):
        seen.append(get_gdal_config("GDAL_NUM_THREADS"))
        return opened(*args, **kwargs)

    monkeypatch.setattr(rasterio, "open", spying_open)

    def write(path, threshold):
        monkeypatch.setattr(layout, "THREADED_COMPRESSION_PIXELS", threshold)
        with dio.output_transaction(), contextlib.ExitStack() as stack:
            out = stack.enter_context(dio.raster_writer(path, height=700, width=900))
            for r0 in range(0, 700, 256):
                out.write(values[r0:r0 + 256], r0, 0)
        return path.read_bytes()

    before = get_gdal_config("GDAL_NUM_THREADS")
    plain = write(tmp_path / "a.tif", 10 ** 9)
    threaded = write(tmp_path / "b.tif", 700 * 900)
    assert seen[0] == before and seen[-1] == "ALL_CPUS"  # only the large one threaded
    assert get_gdal_config("GDAL_NUM_THREADS") == before
    assert threaded == plain
    monkeypatch.setattr(rasterio, "open", opened)
    assert dio.read_raster(tmp_path / "b.tif").data.tobytes() == values.tobytes()
