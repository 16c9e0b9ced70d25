"""The statistics pass of the tiled sensor-model routes (demtool.dem.tiled_map_run):
the gap threshold and the heights' median from cached points tiles, held in memory
(the heights' median beside the gap medians) or streamed, equal numpy's on all points;
and the fill's modules imported ahead (demtool.dem.ahead)."""

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from demtool.dem import tiled_map_run
from demtool.dem.tiled_map import LONLAT_FIELDS, points_tiling, split64
from demtool.tiling import TileCache


def cached_points(folder, rng, outliers: bool):
    """A points cache of 4 tiles (NaN cells without a point; gaps uniform in [0, 1),
    a few of them 1000 with ``outliers``) and the points' decoded gaps and heights."""
    tiling = points_tiling(40, 50, 25)
    cache = TileCache(folder)
    gaps, heights = [], []
    for tile in tiling.tiles:
        h, w = tile.core_shape
        values = {name: rng.normal(size=(h, w)) for name in LONLAT_FIELDS}
        values["gap"] = rng.random((h, w))
        if outliers:
            values["gap"][rng.random((h, w)) < 0.02] = 1000.0
        hole = rng.random((h, w)) < 0.2
        for name in LONLAT_FIELDS:
            values[name][hole] = np.nan
        out = np.concatenate([split64(values[name]) for name in LONLAT_FIELDS])
        cache.store(tile, out, {})
        ok = np.flatnonzero(~hole.ravel())
        # the decoded values (high + low), as the pass reads them
        decoded = {n: out[2 * i].ravel()[ok].astype(np.float64) + out[2 * i + 1].ravel()[ok]
                   for i, n in enumerate(LONLAT_FIELDS)}
        gaps.append(decoded["gap"])
        heights.append(decoded["height"])
    return cache, tiling.tiles, np.concatenate(gaps), np.concatenate(heights)


@pytest.mark.parametrize("in_memory", [True, False])
@pytest.mark.parametrize("max_ray_gap", [None, 0.8])
@pytest.mark.parametrize("outliers", [False, True])
def test_statistics_are_numpys_held_or_streamed(tmp_path, monkeypatch, in_memory,
                                                max_ray_gap, outliers):
    rng = np.random.default_rng(5)
    cache, tiles, gaps, heights = cached_points(tmp_path / "points", rng, outliers)
    if not in_memory:
        monkeypatch.setattr(tiled_map_run, "MEDIAN_IN_MEMORY", 0)
    params = SimpleNamespace(max_ray_gap=max_ray_gap)
    gsd = 0.05
    found = tiled_map_run._statistics(params, cache, tiles, gsd, None,
                                      logging.getLogger("test"))
    median_gap = float(np.median(gaps))
    if max_ray_gap is None:
        nmad = 1.4826 * float(np.median(np.abs(gaps - median_gap)))
        threshold = median_gap + max(4 * nmad, 2 * gsd)
    else:
        threshold = max_ray_gap
    kept = gaps <= threshold
    # every point kept (the heights' median of every point), or some dropped
    assert kept.all() == (max_ray_gap is None and not outliers)
    assert found == (gsd, threshold, median_gap, gaps.size, int(kept.sum()),
                     float(np.median(heights[kept])))


def test_import_ahead_imports_on_a_thread_and_leaves_failures_to_the_user(monkeypatch):
    import sys

    from demtool.dem.ahead import import_ahead

    monkeypatch.delitem(sys.modules, "colorsys", raising=False)
    thread = import_ahead(["demtool.dem.no_such_module", "colorsys"])
    thread.join(10)
    assert not thread.is_alive() and "colorsys" in sys.modules
    assert "demtool.dem.no_such_module" not in sys.modules


def test_import_after_first_tile_imports_once_a_tile_is_done(monkeypatch):
    import sys

    from demtool.dem.ahead import import_after_first_tile

    monkeypatch.delitem(sys.modules, "colorsys", raising=False)
    on_tile = import_after_first_tile(["demtool.dem.no_such_module", "colorsys"])
    on_tile()  # the tiles found in the cache: nothing yet
    assert "colorsys" not in sys.modules
    on_tile()  # the first tile computed
    assert "colorsys" in sys.modules and "demtool.dem.no_such_module" not in sys.modules
    on_tile()
