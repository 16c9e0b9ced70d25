"""Helpers of the tiled ``demtool dem`` (:mod:`demtool.dem.tiled`,
:mod:`demtool.dem.tiled_map`): log histograms and their merged median (the outlier floor
and the median depth over the whole image from per-tile summaries), the grids held as
cached tile cores (a window of them, their block average for the coarse solve), and the
gap fill of both (the coarse global solve, the fine solves of the tiles).
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from demtool.tiling import Tile, TileCache

LOG_LOW = -12.0  # log10 of the smallest value the histograms tell apart

# ------------------------------------------------------------------- histograms, medians
def log_histogram(values: np.ndarray, bins_per_decade: int) -> dict[str, int]:
    """Sparse histogram of ``log10(values)`` (values ≤ 1e-12 in the first bin)."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    index = np.floor((np.log10(np.maximum(values, 10.0**LOG_LOW)) - LOG_LOW)
                     * bins_per_decade).astype(np.int64)
    bins, counts = np.unique(index, return_counts=True)
    return {str(int(b)): int(c) for b, c in zip(bins, counts, strict=True)}


def histogram_median(histograms: list[dict[str, int]], bins_per_decade: int) -> float | None:
    """Median of the values behind merged :func:`log_histogram` s (log-linear in a bin).

    None when the histograms are empty.
    """
    merged: dict[int, int] = {}
    for histogram in histograms:
        for key, count in histogram.items():
            merged[int(key)] = merged.get(int(key), 0) + int(count)
    total = sum(merged.values())
    if total == 0:
        return None
    bins = np.array(sorted(merged))
    counts = np.array([merged[b] for b in bins], dtype=np.float64)
    before = np.cumsum(counts) - counts
    half = 0.5 * total
    i = int(np.searchsorted(before + counts, half))
    position = bins[i] + min(max((half - before[i]) / counts[i], 0.0), 1.0)
    return float(10.0 ** (LOG_LOW + position / bins_per_decade))


# ------------------------------------------------------------------ the cached grid
def _cache_path(folder: Path, index: int) -> Path:
    return TileCache(folder).path(Tile(index, (0, 0, 0, 0), (0, 0, 0, 0)))


def read_cached_window(folder: str | os.PathLike, tile_size: int, shape: tuple[int, int],
                       window: tuple[int, int, int, int], band: int = 0) -> np.ndarray:
    """``[row0, row1) × [col0, col1)`` of a raster held as cached tile cores (float64).

    The cores are those of :func:`demtool.tiling.plan_tiles` (row-major, ``tile_size``
    squares) on a ``shape`` raster; only the cores the window meets are read.
    """
    r0, r1, c0, c1 = window
    columns = math.ceil(shape[1] / tile_size)
    out = np.full((r1 - r0, c1 - c0), np.nan)
    for tr in range(r0 // tile_size, (r1 - 1) // tile_size + 1):
        for tc in range(c0 // tile_size, (c1 - 1) // tile_size + 1):
            core = np.load(_cache_path(Path(folder), tr * columns + tc), mmap_mode="r",
                           allow_pickle=False)[band]
            tr0, tc0 = tr * tile_size, tc * tile_size
            a0, a1 = max(r0, tr0), min(r1, tr0 + core.shape[0])
            b0, b1 = max(c0, tc0), min(c1, tc0 + core.shape[1])
            out[a0 - r0:a1 - r0, b0 - c0:b1 - c0] = core[a0 - tr0:a1 - tr0, b0 - tc0:b1 - tc0]
    return out


def coarse_measured(folder: str | os.PathLike, tiles, shape: tuple[int, int],
                    factor: int) -> np.ndarray:
    """The cached measured grid block-averaged by ``factor`` (NaN where no cell measured)."""
    from demtool.mapproject.threads import ordered_map

    coarse_shape = (math.ceil(shape[0] / factor), math.ceil(shape[1] / factor))
    size = coarse_shape[0] * coarse_shape[1]

    def tile_sums(tile):
        """(True, sums, counts) of one core's measured cells over the flat coarse grid
        when the core starts on a coarse cell's edge (no earlier core shares its coarse
        cells), else (False, flat coarse cells, values)."""
        core = np.load(_cache_path(Path(folder), tile.index), mmap_mode="r",
                       allow_pickle=False)[0]
        r0, _, c0, _ = tile.core
        rows, cols = np.nonzero(np.isfinite(core))
        cells = ((rows + r0) // factor) * coarse_shape[1] + (cols + c0) // factor
        values = np.asarray(core[rows, cols], dtype=np.float64)
        if r0 % factor or c0 % factor:
            return False, cells, values
        # bincount adds each coarse cell's values in their order from 0, as np.add.at
        return True, np.bincount(cells, values, size), np.bincount(cells, minlength=size)

    sums, counts = np.zeros(size), np.zeros(size)
    # the cores on every core, added in tile order: each coarse cell's sum in the order
    # of np.add.at over the tiles one after the other (the same sums)
    for own, a, b in ordered_map(tile_sums, tiles):
        if own:  # its coarse cells are still 0: 0 + its sums, exactly
            sums += a
            counts += b
        else:  # shares coarse cells with an earlier core: after it, in order
            np.add.at(sums, a, b)
            np.add.at(counts, a, 1.0)
    sums, counts = sums.reshape(coarse_shape), counts.reshape(coarse_shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


# ------------------------------------------------------------ the fill (shared)
def coarse_at(work: str | os.PathLike, factor: int, rows: np.ndarray, cols: np.ndarray
              ) -> np.ndarray:
    """The coarse solution ``work/coarse.npy`` at fine cells (bilinear between coarse
    cell centres)."""
    from scipy.ndimage import map_coordinates

    coarse = np.load(Path(work) / "coarse.npy", allow_pickle=False)
    return map_coordinates(coarse, [(rows + 0.5) / factor - 0.5, (cols + 0.5) / factor - 0.5],
                           order=1, mode="nearest")


def fill_core(tile: Tile, shape: tuple[int, int], tile_size: int, *,
              grid: np.ndarray | None = None, work: str | os.PathLike = "", ring: str = "",
              factor: int = 1, median_px: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One fine solve (step 4 of :mod:`demtool.dem.tiled`): the filled core and its measured
    cells.

    ``grid`` (the measured heights on ``tile.outer``, NaN = unmeasured) fills that window
    on its own (a calibration tile); else the window ± one cell is read from the cached
    measured grid ``work/measured`` (band 0, cores of ``tile_size`` on a ``shape`` grid),
    the unmeasured ring held at the earlier sweep ``work/ring`` or the coarse solve.

    Returns (core heights (h, w) float64, measured (h, w) bool).
    """
    from scipy.ndimage import median_filter

    from demtool.errors import ProcessingError
    from demtool.imaging.interpolate import inpaint_springs

    height, width = shape
    r0, r1, c0, c1 = tile.outer
    if grid is not None:
        window = tile.outer
        ring_mask = np.zeros(grid.shape, dtype=bool)
    else:
        window = (r0 - (r0 > 0), r1 + (r1 < height), c0 - (c0 > 0), c1 + (c1 < width))
        grid = read_cached_window(Path(work) / "measured", tile_size, shape, window)
        ring_mask = np.zeros(grid.shape, dtype=bool)
        ring_mask[0, :] |= window[0] < r0
        ring_mask[-1, :] |= window[1] > r1
        ring_mask[:, 0] |= window[2] < c0
        ring_mask[:, -1] |= window[3] > c1
    unknown_ring = ring_mask & ~np.isfinite(grid)
    if unknown_ring.any() and ring:
        earlier = read_cached_window(Path(work) / ring, tile_size, shape, window)
        grid[unknown_ring] = earlier[unknown_ring]
    elif unknown_ring.any():
        rows, cols = np.nonzero(unknown_ring)
        grid[rows, cols] = coarse_at(work, factor, rows + window[0], cols + window[2])
    if not np.isfinite(grid).any():
        raise ProcessingError("no measured height in the tile's window")
    filled = inpaint_springs(grid)
    inner = filled[r0 - window[0]:r1 - window[0], c0 - window[2]:c1 - window[2]]
    if median_px > 1:
        inner = median_filter(inner, size=median_px, mode="nearest")
    rows, cols = tile.crop
    measured = np.isfinite(grid[r0 - window[0]:r1 - window[0],
                                c0 - window[2]:c1 - window[2]][rows, cols])
    return inner[rows, cols], measured


def prepare_fill(measure_job: Any, fill_job: Any, tiles, shape: tuple[int, int],
                 factor: int, folder: Path, *, workers: int, scheduler: str | None,
                 log, sweeps: int = 1) -> Any:
    """Steps 2–3 of :mod:`demtool.dem.tiled` (and ``sweeps`` Schwarz sweeps) in
    ``folder``: the measured grid of ``measure_job`` cached in ``folder/measured``
    (band 0 = heights), its coarse global fill ``folder/coarse.npy``; returns
    ``fill_job`` pointing at them.  Both jobs carry ``work``, ``ring`` and
    ``median_px`` fields (dataclasses)."""
    from demtool.errors import ProcessingError
    from demtool.tiling.distributed import run_tiles

    run_tiles(measure_job, tiles, TileCache(folder / "measured"),
              workers=workers, scheduler=scheduler, log=log)
    coarse_path = folder / "coarse.npy"
    if not coarse_path.is_file():
        from demtool.imaging.interpolate import inpaint_springs

        coarse = coarse_measured(folder / "measured", tiles, shape, factor)
        if not np.isfinite(coarse).any():
            raise ProcessingError("no measured height in the output grid")
        log.info("coarse global fill: %d×%d cells (decimation %d)",
                 coarse.shape[1], coarse.shape[0], factor)
        part = coarse_path.with_name(f"coarse.{os.getpid()}.part.npy")
        np.save(part, inpaint_springs(coarse))
        os.replace(part, coarse_path)
    fill_job = replace(fill_job, work=str(folder))
    for sweep in range(1, sweeps + 1 if factor > 1 else 1):  # Schwarz sweeps, unfiltered
        run_tiles(replace(fill_job, median_px=0), tiles, TileCache(folder / f"sweep{sweep}"),
                  workers=workers, scheduler=scheduler, log=log)
        fill_job = replace(fill_job, ring=f"sweep{sweep}")
    return fill_job
