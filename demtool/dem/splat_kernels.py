"""Compiled kernels of the splatting in :mod:`demtool.dem.grid`.

- :func:`bilinear_moments`: the per-cell weighted moments of
  :func:`demtool.dem.grid.splat_bilinear`, in one pass.  The numpy formulation summed 36
  ``np.bincount`` images (9 moments × the 4 cells each sample reaches) through as many
  temporary arrays of the samples: 1.7 s of a 2048² ``dem``.  This kernel adds the same
  terms in the same order (per corner, samples in their order, each corner's sums then
  added to the total), so the moments are the same bit for bit.
- :func:`cell_medians`: the median of the samples of each cell
  (:func:`demtool.dem.grid.splat_median`), from a counting sort by cell and a stable
  sort within each cell, instead of a lexsort of all samples: the same sorted values, so
  the same medians.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# The four cells a sample at (x0 + fx, y0 + fy) reaches, in the order their sums are
# added: (step_x, step_y), bilinear weight (1 − fx)(1 − fy), fx(1 − fy), (1 − fx)fy, fx·fy.
CORNERS = ((0, 0), (1, 0), (0, 1), (1, 1))


@njit(nogil=True, cache=True)
def _corner_sums(x, y, z, height, width, step_x, step_y, sums):
    """Sums (9, H·W) of w, w·dx, w·dy, w·dx², w·dx·dy, w·dy², w·z, w·z·dx, w·z·dy over the
    samples whose corner (step_x, step_y) lies in the grid with weight > 0; dx, dy are
    the offsets sample − cell centre."""
    sums[:] = 0.0
    for j in range(len(x)):
        col0, row0 = np.floor(x[j]), np.floor(y[j])
        fx, fy = x[j] - col0, y[j] - row0
        wx = fx if step_x else 1 - fx
        wy = fy if step_y else 1 - fy
        w = wx * wy
        col, row = np.int64(col0) + step_x, np.int64(row0) + step_y
        if not (col >= 0 and col < width and row >= 0 and row < height and w > 0):
            continue
        cell = row * width + col
        dx, dy, zj = fx - step_x, fy - step_y, z[j]
        sums[0, cell] += w
        sums[1, cell] += w * dx
        sums[2, cell] += w * dy
        sums[3, cell] += w * dx * dx
        sums[4, cell] += w * dx * dy
        sums[5, cell] += w * dy * dy
        sums[6, cell] += w * zj
        sums[7, cell] += w * zj * dx
        sums[8, cell] += w * zj * dy


def bilinear_moments(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                     shape: tuple[int, int]) -> np.ndarray:
    """Weighted moments per cell of bilinearly splatted samples.

    Parameters
    ----------
    x, y : (N,) float64
        Finite sample positions, pixels (cell centres at integers).
    z : (N,) float64
        Finite sample values.
    shape : (H, W)

    Returns
    -------
    (9, H·W) float64
        Σw, Σw·dx, Σw·dy, Σw·dx², Σw·dx·dy, Σw·dy², Σw·z, Σw·z·dx, Σw·z·dy over the
        samples reaching each cell (bilinear weights w; offsets sample − cell centre).
    """
    height, width = shape
    x, y, z = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, z))
    # the first corner's sums are the total so far (0 + s is s: a sum from +0 is never −0)
    moments = np.empty((9, height * width))
    _corner_sums(x, y, z, height, width, *CORNERS[0], moments)
    sums = np.empty_like(moments)
    for step_x, step_y in CORNERS[1:]:
        _corner_sums(x, y, z, height, width, step_x, step_y, sums)
        moments += sums
    return moments


@njit(nogil=True, cache=True)
def _cell_medians(cells, values, counts, grid):
    """``grid[c]`` = median of ``values[cells == c]`` (0.5 · (lower + upper) middle values)
    for every cell with ``counts[c]`` > 0."""
    starts = np.zeros(len(counts) + 1, dtype=np.int64)
    for c in range(len(counts)):
        starts[c + 1] = starts[c] + counts[c]
    fill = starts[:-1].copy()
    bucket = np.empty(len(values))
    for j in range(len(values)):  # in sample order: each cell's values stay in that order
        bucket[fill[cells[j]]] = values[j]
        fill[cells[j]] += 1
    for c in range(len(counts)):
        size = counts[c]
        if size == 0:
            continue
        segment = bucket[starts[c]:starts[c + 1]]
        if size <= 64:  # stable insertion sort
            for i in range(1, size):
                value = segment[i]
                j = i
                while j > 0 and segment[j - 1] > value:
                    segment[j] = segment[j - 1]
                    j -= 1
                segment[j] = value
        else:
            segment[:] = segment[np.argsort(segment, kind="mergesort")]
        grid[c] = 0.5 * (segment[(size - 1) // 2] + segment[size // 2])


def cell_medians(cells: np.ndarray, values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Median of the values falling in each cell.

    Parameters
    ----------
    cells : (N,) int64
        Flat cell index of each sample, 0 … C − 1.
    values : (N,) float64
        Finite sample values.
    counts : (C,) int64
        Samples per cell (``np.bincount(cells, minlength=C)``).

    Returns
    -------
    (C,) float64
        The mean of the two middle values (the middle one for an odd count); NaN where
        no sample fell.
    """
    grid = np.full(len(counts), np.nan)
    _cell_medians(np.ascontiguousarray(cells, dtype=np.int64),
                  np.ascontiguousarray(values, dtype=np.float64),
                  np.ascontiguousarray(counts, dtype=np.int64), grid)
    return grid
