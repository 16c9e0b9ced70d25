"""The outputs of a tiled run written while its tiles are computed (run_tiled's
in-order writer) are the file write_tiled_raster makes from the finished cache."""

from __future__ import annotations

import numpy as np

from demtool import tiling
from demtool.tiling.jobs import TiledOutput, _InOrderWriter


def test_tiles_written_as_they_finish_give_the_same_bytes(tmp_path):
    plan = tiling.plan_tiles(300, 520, 128, overlap=4)
    rng = np.random.default_rng(1)
    values = {t.index: rng.normal(size=(2, *t.core_shape)).astype(np.float32)
              for t in plan.tiles}
    values[3][0, :5] = np.nan
    whole = tiling.TileCache(tmp_path / "whole")
    for tile in plan.tiles:
        whole.store(tile, values[tile.index], {})
    tags = {"demtool_stage": "test"}
    tiling.write_tiled_raster(tmp_path / "a.tif", plan, whole, band=[0, 1], tags=tags,
                              band_name=["disparity", "confidence"])

    # the same tiles finishing out of order, the writer advanced after each
    growing = tiling.TileCache(tmp_path / "growing")
    import contextlib

    with contextlib.ExitStack() as stack:
        writer = _InOrderWriter(stack, [TiledOutput(tmp_path / "b.tif", [0, 1], tags,
                                                    ["disparity", "confidence"])],
                                plan, growing, None, None)
        writer.advance()  # nothing finished yet
        assert writer.next == 0
        order = rng.permutation(len(plan.tiles))
        for count, index in enumerate(order, start=1):
            growing.store(plan.tiles[index], values[index], {})
            writer.advance()
            done = {int(i) for i in order[:count]}
            expected = 0
            while expected in done:
                expected += 1
            assert writer.next == expected  # every finished tile before the first gap
        writer.finish()
    assert (tmp_path / "b.tif").read_bytes() == (tmp_path / "a.tif").read_bytes()


def test_tiled_outputs_compress_as_the_untiled_writers(tmp_path):
    """deflate level 1 (demtool.io.write_raster's) by default, ZSTD level 1 (raster_writer's)
    when asked; the same values either way; an unknown name refused."""
    import pytest
    import rasterio

    plan = tiling.plan_tiles(300, 520, 128, overlap=0)
    rng = np.random.default_rng(2)
    cache = tiling.TileCache(tmp_path / "cache")
    for tile in plan.tiles:
        cache.store(tile, rng.normal(size=(1, *tile.core_shape)).astype(np.float32), {})
    tiling.write_tiled_raster(tmp_path / "d.tif", plan, cache)
    tiling.write_tiled_raster(tmp_path / "z.tif", plan, cache, compress="zstd")
    with rasterio.open(tmp_path / "d.tif") as deflate, rasterio.open(tmp_path / "z.tif") as zstd:
        assert deflate.compression.name == "deflate" and zstd.compression.name == "zstd"
        assert np.array_equal(deflate.read(1), zstd.read(1), equal_nan=True)
    with pytest.raises(ValueError, match="unknown compression 'lzw'"):
        tiling.write_tiled_raster(tmp_path / "l.tif", plan, cache, compress="lzw")


def test_the_workers_forkserver_starts_early_only_for_local_workers():
    from demtool.sgm import warm
    from demtool.sgm.tiled import SgmTileJob
    from demtool.tiling.distributed import prestart_local_workers

    assert warm.load_kernels()  # what the forkserver runs at import: never raises
    assert "demtool.sgm.warm" in SgmTileJob.preload
    assert not prestart_local_workers(SgmTileJob, 1)  # tiles in this process
    assert not prestart_local_workers(SgmTileJob, 2, scheduler="tcp://127.0.0.1:9")
    assert not prestart_local_workers(SgmTileJob, 2, dry_run=True)
