"""What a refine tile costs (issue 47): each tile is refined on a window whose sides are
fast DCT lengths and multiples of 4 (a 2048-px core with its 113-px margins is 2161 px, a
prime: 5× the DCT time per pixel and Egrad's low-pass on full-resolution samples), and
the tile job reads, refines and crops exactly that window."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from demtool.refine.tile_window import FAST_FACTORS, fast_length, solve_window
from demtool.refine.tiled import RefineTileJob
from demtool.tiling import plan_tiles


def largest_prime_factor(n: int) -> int:
    factor, largest = 2, 1
    while factor * factor <= n:
        while n % factor == 0:
            largest, n = factor, n // factor
        factor += 1
    return max(largest, n) if n > 1 else largest


def test_fast_length_is_the_smallest_fast_multiple_of_four():
    assert fast_length(2161) == 2200  # 2161 is prime; 2200 = 2³·5²·11
    assert fast_length(1137) == 1152  # 3·379 → 2⁷·3²
    assert fast_length(2048) == 2048 and fast_length(305) == 308 and fast_length(1) == 4
    for n in range(1, 3000):
        m = fast_length(n)
        assert m >= n and m % 4 == 0 and largest_prime_factor(m) <= max(FAST_FACTORS)
        # nothing fast in between
        assert all(k % 4 or largest_prime_factor(k) > 11 for k in range(n, m))


@pytest.mark.parametrize("grid,size,overlap", [((4096, 4096), 2048, 113), ((384, 384), 192, 113),
                                               ((3001, 517), 1024, 113), ((70, 5000), 64, 30)])
def test_solve_window_holds_the_outer_window_inside_the_grid(grid, size, overlap):
    tiling = plan_tiles(*grid, size, overlap=overlap)
    for tile in tiling.tiles:
        window = solve_window(tile.outer, grid)
        r0, r1, c0, c1 = window
        assert 0 <= r0 <= tile.outer[0] and tile.outer[1] <= r1 <= grid[0]
        assert 0 <= c0 <= tile.outer[2] and tile.outer[3] <= c1 <= grid[1]
        for length, side, outer in ((r1 - r0, grid[0], tile.outer_shape[0]),
                                    (c1 - c0, grid[1], tile.outer_shape[1])):
            # a fast length, or the grid's whole side where that is shorter
            assert length == fast_length(outer) or (length == side and
                                                   fast_length(outer) >= side)


def test_the_tile_job_refines_and_crops_its_solve_window(tmp_path, monkeypatch):
    """compute() reads the grown window and returns the core's pixels of its refinement."""
    from demtool import io
    from demtool.refine import make_illumination, refine_heights, tiled
    from demtool.refine.params import RefineParams
    from demtool.refine.prepare import prepare_dem

    size = 200
    rows, cols = np.indices((size, size), dtype=np.float32)
    ramp = 0.01 * cols + 0.02 * rows + np.sin(rows / 7.0)  # heights, m
    image = np.full((size, size), 100.0, np.float32) * (1 + 0.01 * np.sin(cols / 3.0))
    dem_path, image_path = tmp_path / "dem.tif", tmp_path / "image.tif"
    io.write_raster(dem_path, ramp, transform=io.image_frame_transform(1.0))
    io.write_raster(image_path, image, transform=io.image_frame_transform(1.0))
    params = RefineParams(iterations=2, median=0)
    options = {k: v for k, v in params.as_dict().items()
               if k not in ("workers", "tile_size", "tile_overlap", "scheduler", "dry_run")}
    job = RefineTileJob(str(image_path), str(dem_path), (1.0, 1.0), (0.5, 0.0, 0.866),
                        (0.0, 0.0, 1.0), 100.0, tuple(sorted(options.items())),
                        grid=(size, size))
    read = []
    original = tiled.read_window
    monkeypatch.setattr(tiled, "read_window", lambda path, window, **kw: (
        read.append(window), original(path, window, **kw))[1])
    tile = next(t for t in plan_tiles(size, size, 64, overlap=25).tiles
                if t.core == (64, 128, 64, 128))  # an interior tile: 64 + 2·25 px
    out, info = job.compute(tile, 1)
    assert read == [solve_window(tile.outer, (size, size))] * 2
    assert tile.outer == (39, 153, 39, 153) and read[0] == (36, 156, 36, 156)  # 114 → 120
    assert job.memory_bytes(tile) == tiled.PROCESS_BYTES + 120 * 120 * tiled.BYTES_PER_PIXEL
    r0, r1, c0, c1 = tile.core
    assert out.shape == (2, 64, 64) and info["iterations"] == 2
    # the core of the same refinement of the whole window (a misplaced crop differs)
    w0, w1, v0, v1 = read[0]
    prepared = prepare_dem(ramp[w0:w1, v0:v1], median_size=0, start_sigma=params.start_sigma)
    whole = refine_heights(image[w0:w1, v0:v1], prepared.dem, spacing=(1.0, 1.0),
                           illumination=make_illumination(job.sun, job.view),
                           parameters=params.sfs(), initial=prepared.initial,
                           image_median=100.0)
    assert np.array_equal(out[0], whole.dem[r0 - w0:r1 - w0, c0 - v0:c1 - v0])
    assert np.array_equal(out[1], whole.albedo[r0 - w0:r1 - w0, c0 - v0:c1 - v0])


def test_tiles_on_threads_match_tiles_one_after_the_other(tmp_path):
    """Local --workers N runs refine tiles on N threads of one process: a tile's numbers
    must not depend on what runs beside it (no process-wide state changed per tile)."""
    from concurrent.futures import ThreadPoolExecutor

    from demtool import io
    from demtool.refine.params import RefineParams
    from demtool.tiling.tasks import numba_threads_at_most

    size = 160
    rng = np.random.default_rng(2)
    rows, cols = np.indices((size, size), dtype=np.float32)
    dem = np.sin(rows / 9.0) + np.cos(cols / 7.0) + 0.05 * rng.normal(size=(size, size))
    image = 100 + 20 * np.cos(cols / 7.0) + rng.normal(size=(size, size))
    dem_path, image_path = tmp_path / "dem.tif", tmp_path / "image.tif"
    io.write_raster(dem_path, dem.astype(np.float32), transform=io.image_frame_transform(1.0))
    io.write_raster(image_path, image.astype(np.float32),
                    transform=io.image_frame_transform(1.0))
    params = RefineParams(iterations=3, update_every=2)  # the median and albedo updates
    options = {k: v for k, v in params.as_dict().items()
               if k not in ("workers", "tile_size", "tile_overlap", "scheduler", "dry_run")}
    job = RefineTileJob(str(image_path), str(dem_path), (1.0, 1.0), (0.5, 0.0, 0.866),
                        (0.0, 0.0, 1.0), 100.0, tuple(sorted(options.items())),
                        grid=(size, size))
    tiles = plan_tiles(size, size, 80, overlap=30).tiles
    before = numba.get_num_threads()

    def computed(tile, threads):  # as tiling.tasks.compute_tile scopes the thread count
        with numba_threads_at_most(threads):
            return job.compute(tile, threads)[0]

    alone = [computed(tile, 1) for tile in tiles]
    with ThreadPoolExecutor(2) as pool:
        beside = list(pool.map(lambda tile: computed(tile, 1), tiles))
    with_cores = [computed(tile, 2) for tile in tiles[:1]]  # median in strips
    for a, b in zip(alone, beside, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.array_equal(alone[0], with_cores[0], equal_nan=True)
    assert numba.get_num_threads() == before  # the calling thread's count, restored
