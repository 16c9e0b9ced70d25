"""The windowed compare's passes (demtool.compare.window_passes): the rasters read once,
the differences kept for the later passes, the windows on two threads, the compiled
binning of the order statistics; every way gives the numbers of reading every window
again in every pass on one thread, to the bit."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from demtool import io as dio
from demtool.compare import threads, window_passes
from demtool.compare.params import CompareParams
from demtool.compare.run import run_compare
from demtool.compare.streaming import (
    ABSOLUTE,
    AS_GIVEN,
    DEVIATION,
    Moments,
    _gather,
    _narrow,
)
from demtool.tiling.rows import ordered_map
from tests.helpers.compare import fractal

REFERENCE_GSD = 2.0


@pytest.mark.parametrize("kind", ["normal", "rounded", "heavy tails", "constant"])
def test_the_compiled_binning_counts_as_searchsorted(kind):
    rng = np.random.default_rng(7)
    values = {"normal": rng.normal(size=3001) * 10.0 ** rng.uniform(-4, 4),
              "rounded": np.round(rng.normal(size=3001), 1),
              "heavy tails": rng.standard_t(1.5, size=3001) * 1e3,
              "constant": np.full(3001, 3.25)}[kind]
    centre = float(values[17])
    for bins in (2, 16, 4096):
        for mode, seen in ((AS_GIVEN, values), (ABSOLUTE, np.abs(values)),
                           (DEVIATION, np.abs(values - centre))):
            low, high = float(np.quantile(seen, 0.2)), float(np.quantile(seen, 0.8))
            high = float(np.nextafter(high, np.inf))
            edges = np.unique(np.linspace(low, high, bins + 1))
            if edges.size < 3:
                edges = np.array([low, np.nextafter(low, np.inf), high])
            counts = np.zeros(edges.size - 1, dtype=np.int64)
            below = _narrow(values, mode, centre, low, high, edges, counts)
            inside = seen[(seen >= low) & (seen < high)]
            index = np.searchsorted(edges, inside, side="right") - 1
            assert below == np.count_nonzero(seen < low)
            np.testing.assert_array_equal(counts, np.bincount(index, minlength=counts.size))
            gathered_below, kept = _gather(values, mode, centre, low, high)
            assert gathered_below == below
            np.testing.assert_array_equal(kept, inside)


def test_moments_summarised_apart_and_merged_in_order_are_added_in_order():
    rng = np.random.default_rng(8)
    pieces = [500.0 + rng.normal(size=n) for n in (1000, 0, 3, 777)]
    added, merged = Moments(), Moments()
    for piece in pieces:
        added.add(piece)
    for summary in [Moments.of(p) for p in reversed(pieces)][::-1]:
        merged.merge(summary)
    assert vars(added) == vars(merged)  # to the bit


def test_windows_on_two_threads_come_in_order_and_raise_in_place():
    def slow_first(item):
        time.sleep(0.05 if item == 0 else 0.0)
        if item == 3:
            raise ValueError("item 3")
        return item * 10

    got = []
    with pytest.raises(ValueError, match="item 3"):
        for value in ordered_map(slow_first, range(6), threads=2):
            got.append(value)
    assert got == [0, 10, 20]
    assert list(ordered_map(lambda i: -i, range(5), threads=1)) == [0, -1, -2, -3, -4]


@pytest.fixture(scope="module")
def projected_pair(tmp_path_factory):
    """A 90² reference on an equirectangular map of the Moon (2 m) with a hole, a DEM of
    the same ground at 1.5 m on another equirectangular map (PROJ transforms every cell)
    shifted by about a cell and 2 m, and a mask on the reference's grid."""
    from affine import Affine
    from pyproj import Transformer
    from scipy import ndimage

    from demtool.maps import body_by_name
    from demtool.maps.projections import make_projection

    folder = tmp_path_factory.mktemp("window_passes")
    moon = body_by_name("Moon")
    reference_crs = make_projection(moon, "equirectangular", 0.0, 10.0)
    dem_crs = make_projection(moon, "equirectangular", 0.002, 10.0)
    surface = fractal(180, relief=30.0, seed=3)  # 1 m cells over the reference's 180 m
    truth = surface.reshape(90, 2, 90, 2).mean(axis=(1, 3))
    truth[60:66, 10:30] = np.nan
    reference_transform = Affine(REFERENCE_GSD, 0, -90.0, 0, -REFERENCE_GSD, 90.0)
    dio.write_raster(folder / "reference.tif", truth, transform=reference_transform,
                     crs=reference_crs.to_wkt())
    to_dem = Transformer.from_crs(reference_crs, dem_crs, always_xy=True)
    x0, y0 = to_dem.transform(-85.0, 85.0)
    dem_transform = Affine(1.5, 0, x0, 0, -1.5, y0)
    cols, rows = np.meshgrid(np.arange(110) + 0.5, np.arange(110) + 0.5)
    x, y = to_dem.transform(x0 + 1.5 * cols, y0 - 1.5 * rows, direction="INVERSE")
    dem = ndimage.map_coordinates(surface, [90.0 - y - 0.5 - 0.8, x + 90.0 - 0.5 + 1.1],
                                  order=1, mode="nearest") + 2.0
    dem[30:36, 40:70] = np.nan
    dio.write_raster(folder / "dem.tif", dem, transform=dem_transform, crs=dem_crs.to_wkt())
    mask = np.ones(truth.shape, dtype=np.float32)
    mask[:, 70:] = 0.0
    dio.write_raster(folder / "mask.tif", mask, transform=reference_transform,
                     crs=reference_crs.to_wkt())
    return folder


def _run(folder, out):
    report = run_compare(folder / "dem.tif", folder / "reference.tif", out,
                         CompareParams(tile_size=32, plots=False),
                         mask_path=folder / "mask.tif")
    difference = dio.read_raster(out / "difference.tif", what="difference").data
    report = json.loads(json.dumps({k: v for k, v in report.items() if k != "provenance"}))
    report["windowed"].pop("largest_read_cells")  # cores with the grid kept, else windows
    return report, difference


@pytest.mark.slow
def test_every_way_through_the_passes_gives_the_same_numbers(projected_pair, tmp_path,
                                                             monkeypatch, caplog):
    """Reading every window in every pass on one thread (as before the passes kept
    anything) against: the grid and the differences kept, on two threads; the first
    windows' differences kept and the others read again in every pass, on two threads."""
    def way(grid_bytes, kept_bytes, two, name):
        monkeypatch.setattr(window_passes, "GRID_BYTES_PER_CELL", grid_bytes)
        monkeypatch.setattr(window_passes, "KEPT_BYTES_PER_CELL", kept_bytes)
        monkeypatch.setattr(threads, "THREADED_CELLS", 0 if two else 1 << 40)
        return _run(projected_pair, tmp_path / name)

    budget = CompareParams().max_memory_mb * 2**20 - 90 * 90 * 400  # what the alignment leaves
    want, want_difference = way(budget, budget, False, "every_pass_reads")
    assert want["windowed"]["windows"] == 9 and want["windowed"]["passes"] >= 3
    assert want["count"] > 3000 and 0 < want["completeness"] < 100
    assert abs(want["shift"]["dx_px"]) > 0.3  # the DEM is shifted and resampled
    some = int(budget // (4.5 * 32 * 32))  # the first four windows kept, five read again
    for name, grid_bytes, kept_bytes, two, again in [
            ("kept_two_threads", 17, 16, True, "(0 reading the rasters again)"),
            ("some_kept_two_threads", budget, some, True, "(5 reading the rasters again)")]:
        caplog.clear()
        with caplog.at_level("INFO", logger="demtool"):
            got, difference = way(grid_bytes, kept_bytes, two, name)
        assert any(again in r.getMessage() for r in caplog.records), name
        assert got == want, name
        np.testing.assert_array_equal(difference, want_difference)
