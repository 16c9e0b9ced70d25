"""The tiled dem's coarse grid (demtool.dem.tiled_grids.coarse_measured): the cores'
measured cells block-averaged, on every core, with the sums np.add.at gives over the
tiles one after the other, to the bit (cores on and off the coarse cells' edges)."""

import math

import numpy as np
import pytest

from demtool.dem.tiled_grids import coarse_measured
from demtool.tiling import TileCache, plan_tiles


@pytest.mark.parametrize("shape, tile_size, factor", [
    ((300, 250), 64, 4),  # every core starts on a coarse cell's edge
    ((257, 250), 64, 3),  # cores sharing coarse cells with earlier ones
    ((130, 190), 64, 1)])
def test_coarse_measured_is_the_in_order_block_average(tmp_path, shape, tile_size, factor):
    rng = np.random.default_rng(5)
    grid = rng.normal(1700.0, 300.0, shape).astype(np.float32)
    grid[rng.random(shape) < 0.3] = np.nan  # unmeasured cells
    grid[:40, :50] = np.nan  # a coarse region without any measured cell
    tiles = plan_tiles(*shape, tile_size, overlap=0).tiles
    cache = TileCache(tmp_path)
    for tile in tiles:
        r0, r1, c0, c1 = tile.core
        cache.store(tile, grid[None, r0:r1, c0:c1], {})
    coarse = (math.ceil(shape[0] / factor), math.ceil(shape[1] / factor))
    sums, counts = np.zeros(coarse), np.zeros(coarse)
    for tile in tiles:  # the definition: every measured cell added in tile order
        r0, r1, c0, c1 = tile.core
        rows, cols = np.nonzero(np.isfinite(grid[r0:r1, c0:c1]))
        cells = (rows + r0) // factor, (cols + c0) // factor
        np.add.at(sums, cells, grid[r0:r1, c0:c1][rows, cols].astype(np.float64))
        np.add.at(counts, cells, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        want = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    got = coarse_measured(tmp_path, tiles, shape, factor)
    assert np.isnan(got).any() and np.isfinite(got).mean() > 0.5
    assert np.array_equal(got, want, equal_nan=True)
