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


def test_the_workers_forkserver_starts_early_only_for_local_workers():
    from demtool.sgm import warm
    from demtool.sgm.tiled import SgmTileJob
    from demtool.tiling.distributed import prestart_local_workers

    assert warm.load_kernels()  # what the forkserver runs at import: never raises
    assert "demtool.sgm.warm" in SgmTileJob.preload
    assert not prestart_local_workers(SgmTileJob, 1)  # tiles in this process
    assert not prestart_local_workers(SgmTileJob, 2, scheduler="tcp://127.0.0.1:9")
    assert not prestart_local_workers(SgmTileJob, 2, dry_run=True)
