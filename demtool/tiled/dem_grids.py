"""Helpers of the tiled ``demtool dem`` (:mod:`demtool.tiled.dem`): log histograms and
their merged median (the outlier floor and the median depth over the whole image from
per-tile summaries), and the grids held as cached tile cores (a window of them, their
block average for the coarse solve).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

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
    coarse_shape = (math.ceil(shape[0] / factor), math.ceil(shape[1] / factor))
    sums, counts = np.zeros(coarse_shape), np.zeros(coarse_shape)
    for tile in tiles:
        core = np.load(_cache_path(Path(folder), tile.index), mmap_mode="r",
                       allow_pickle=False)[0]
        r0, _, c0, _ = tile.core
        rows, cols = np.nonzero(np.isfinite(core))
        cells = (rows + r0) // factor, (cols + c0) // factor
        np.add.at(sums, cells, np.asarray(core[rows, cols], dtype=np.float64))
        np.add.at(counts, cells, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
