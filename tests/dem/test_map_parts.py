"""dem_on_map's numpy steps on row parts (demtool.dem.map_parts): the whole-array
results bit for bit, on one thread or several, parts with no finite value included."""

import numpy as np
import pytest

from demtool.dem import map_parts
from demtool.tiling.tasks import numba_threads_at_most, threads_limited


@pytest.fixture
def small_parts(monkeypatch):
    """Parts and batches of a few elements, so that small arrays are cut into several."""
    from demtool.mapproject import threads

    monkeypatch.setattr(map_parts, "MIN_PART_ELEMENTS", 64)
    monkeypatch.setattr(threads, "MIN_BATCH", 100)


def _on_one_thread(function, *args, **options):
    with threads_limited(1), numba_threads_at_most(1):
        return function(*args, **options)


def test_point_steps_equal_numpy(small_parts):
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(5000, 3)) * 1e3
    xyz[rng.random(5000) < 0.05, 1] = np.nan
    x, y = xyz[:, 0].copy(), xyz[:, 1].copy()
    x[:1000] = np.nan  # a part without a finite point
    np.testing.assert_array_equal(map_parts.finite_points(xyz), np.isfinite(xyz).all(axis=1))
    good = np.isfinite(x) & np.isfinite(y)
    assert map_parts.finite_extent(x, y) == (x[good].min(), y[good].min(), x[good].max(),
                                             y[good].max())
    assert map_parts.finite_extent(np.full(300, np.nan), np.zeros(300)) is None

    class North:  # a north-up transform's terms
        a, c, e, f = 0.7, -12.5, -0.7, 40.25

    pixels = map_parts.map_pixels(x, y, North)
    expected = np.stack([(x - North.c) / North.a - 0.5, (y - North.f) / North.e - 0.5], -1)
    np.testing.assert_array_equal(pixels.view(np.uint64), expected.view(np.uint64))
    np.testing.assert_array_equal(map_parts.point_columns(x, y, xyz[:, 2]),
                                  np.column_stack([x, y, xyz[:, 2]]))

    def function(a, b):  # (N, 3) float64, (N,) bool and (N,) float64 results
        return np.stack([a, b, a * b], axis=-1), a > b, a + b

    from demtool.mapproject.threads import batched

    one = _on_one_thread(batched, function, x, y)
    many = batched(function, x, y)
    for a, b, c in zip(one, many, function(x, y), strict=True):
        assert a.dtype == b.dtype == c.dtype and a.shape == b.shape == c.shape
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


@pytest.mark.parametrize("median_px", [0, 3])
def test_finish_grid_equals_the_whole_array_steps(small_parts, median_px):
    rng = np.random.default_rng(4)
    dem = rng.normal(size=(40, 30))
    dem[rng.random(dem.shape) < 0.2] = np.nan
    dem[:6] = np.nan  # parts with no height at all
    error = rng.random(dem.shape)
    counts = rng.integers(1, 5, dem.shape)
    overlap = rng.random(dem.shape) < 0.7
    overlap[:3] = False
    full = np.where(np.isfinite(dem), dem, 7.5) + 0.25 * (median_px > 1)
    for given in (full, None):
        # the steps as dem_on_map made them before they were cut into parts
        measured = np.isfinite(dem)
        seen = overlap | measured
        filled = np.zeros(dem.shape, dtype=bool)
        out = dem.copy()
        if given is not None:
            filled = seen & ~measured
            out = np.where(filled | (median_px > 1), given, dem)
        out[~seen] = np.nan
        for run in (map_parts.finish_grid, lambda *a: _on_one_thread(map_parts.finish_grid, *a)):
            mask = overlap.copy()
            done = run(dem, error, counts, mask, given, median_px)
            np.testing.assert_array_equal(mask, seen)
            np.testing.assert_array_equal(done.dem.view(np.uint32),
                                          out.astype(np.float32).view(np.uint32))
            np.testing.assert_array_equal(done.error, error.astype(np.float32))
            np.testing.assert_array_equal(done.filled, filled)
            assert (done.measured_cells, done.overlap_cells, done.filled_cells) == (
                int(measured.sum()), int(seen.sum()), int(filled.sum()))
            assert done.points_per_measured_cell == float(counts[measured].mean())
            assert (done.height_min, done.height_max) == (float(np.nanmin(out)),
                                                          float(np.nanmax(out)))
