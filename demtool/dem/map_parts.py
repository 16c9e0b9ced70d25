"""The numpy steps of :func:`demtool.dem.sensors.dem_on_map` between its kernels, on
every core: each step is cut into contiguous parts of its points (or of the map's rows)
run at once by :func:`demtool.tiling.rows.on_row_parts` (numpy's loops release the GIL).

Every element is computed by the same operations as one whole-array call, so the
results are the same bit for bit on any number of threads; the reductions are exact
(counts, minima and maxima, sums of integer counts), so their parts combine to the
whole-array value.  On a 2048² map these steps were about 0.5 CPU s on one core of the
grid phase's 4–5 (issue 47).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Fewest points (or map cells, counted as rows × columns) worth a part of their own.
MIN_PART_ELEMENTS = 1 << 16


def _parts(work, count: int, elements_per_row: int = 1) -> None:
    from demtool.tiling.rows import on_row_parts

    min_rows = max(1, MIN_PART_ELEMENTS // max(1, int(elements_per_row)))
    on_row_parts(work, int(count), min_rows=min_rows)


def finite_points(xyz: np.ndarray) -> np.ndarray:
    """``np.isfinite(xyz).all(axis=1)`` of (N, 3) points, (N,) bool."""
    keep = np.empty(len(xyz), dtype=bool)

    def work(start: int, stop: int) -> None:
        np.isfinite(xyz[start:stop]).all(axis=1, out=keep[start:stop])

    _parts(work, len(xyz))
    return keep


def finite_extent(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float] | None:
    """(x min, y min, x max, y max) of the points whose x and y are both finite (as
    ``x[good].min()``… with ``good = isfinite(x) & isfinite(y)``); None when none is."""
    from demtool.tiling.rows import row_parts

    parts = row_parts(len(x), min_rows=MIN_PART_ELEMENTS)
    found: list[tuple[float, float, float, float] | None] = [None] * len(parts)
    starts = {start: i for i, (start, _) in enumerate(parts)}

    def work(start: int, stop: int) -> None:
        px, py = x[start:stop], y[start:stop]
        good = np.isfinite(px) & np.isfinite(py)
        if good.all():
            found[starts[start]] = (px.min(), py.min(), px.max(), py.max())
        elif good.any():
            gx, gy = px[good], py[good]
            found[starts[start]] = (gx.min(), gy.min(), gx.max(), gy.max())

    _parts(work, len(x))
    extents = [f for f in found if f is not None]
    if not extents:
        return None
    return (float(min(e[0] for e in extents)), float(min(e[1] for e in extents)),
            float(max(e[2] for e in extents)), float(max(e[3] for e in extents)))


def map_pixels(x: np.ndarray, y: np.ndarray, transform) -> np.ndarray:
    """(N, 2) pixel positions (column, row) of map points on a north-up grid, pixel
    centres at integers: ``(x − c) / a − 0.5``, ``(y − f) / e − 0.5``."""
    pixels = np.empty((len(x), 2))
    c, a, f, e = transform.c, transform.a, transform.f, transform.e

    def work(start: int, stop: int) -> None:
        np.subtract((x[start:stop] - c) / a, 0.5, out=pixels[start:stop, 0])
        np.subtract((y[start:stop] - f) / e, 0.5, out=pixels[start:stop, 1])

    _parts(work, len(x))
    return pixels


def point_columns(*columns: np.ndarray) -> np.ndarray:
    """``np.column_stack(columns)`` of (N,) float64 arrays, (N, len(columns))."""
    out = np.empty((len(columns[0]), len(columns)))

    def work(start: int, stop: int) -> None:
        for j, column in enumerate(columns):
            out[start:stop, j] = column[start:stop]

    _parts(work, len(out))
    return out


class FinishedGrid(NamedTuple):
    """The DEM grid of :func:`finish_grid` and its figures."""

    dem: np.ndarray  # (H, W) float32, NaN outside the overlap
    error: np.ndarray  # (H, W) float32
    filled: np.ndarray  # (H, W) bool
    measured_cells: int
    overlap_cells: int
    filled_cells: int
    points_per_measured_cell: float
    height_min: float  # NaN when no cell has a height
    height_max: float


def finish_grid(dem: np.ndarray, error: np.ndarray, counts: np.ndarray,
                overlap: np.ndarray, full: np.ndarray | None,
                median_px: int) -> FinishedGrid:
    """The last steps of :func:`demtool.dem.sensors.dem_on_map`, on row parts.

    ``overlap`` (H, W) bool is updated in place to include the measured cells; where
    ``full`` (the filled grid, or None) is given, the unmeasured cells of the overlap
    (and every cell with a median filter, ``median_px`` > 1) take its values; cells
    outside the overlap are NaN.  Heights float64 → float32 as ``astype``.
    """
    height, width = dem.shape
    out = np.empty(dem.shape, dtype=np.float32)
    error32 = np.empty(dem.shape, dtype=np.float32)
    filled = np.zeros(dem.shape, dtype=bool)
    figures: dict[int, tuple] = {}

    def work(start: int, stop: int) -> None:
        part = dem[start:stop]
        measured = np.isfinite(part)
        seen = overlap[start:stop]
        seen |= measured
        values = part.copy()
        if full is not None:
            gaps = filled[start:stop]
            np.logical_and(seen, ~measured, out=gaps)
            values = np.where(gaps | (median_px > 1), full[start:stop], part)
        values[~seen] = np.nan
        low = high = np.nan
        if not np.isnan(values).all():
            low, high = np.nanmin(values), np.nanmax(values)
        out[start:stop] = values
        error32[start:stop] = error[start:stop]
        figures[start] = (int(measured.sum()), int(seen.sum()),
                          int(filled[start:stop].sum()),
                          int(counts[start:stop][measured].sum()), low, high)

    _parts(work, height, width)
    parts = [figures[start] for start in sorted(figures)]
    measured_cells = sum(p[0] for p in parts)
    lows = [p[4] for p in parts if not np.isnan(p[4])]
    highs = [p[5] for p in parts if not np.isnan(p[5])]
    return FinishedGrid(
        out, error32, filled, measured_cells, sum(p[1] for p in parts),
        sum(p[2] for p in parts),
        # np.mean of the integer counts: their exact sum (float64) over the number
        float(np.float64(sum(p[3] for p in parts)) / measured_cells) if measured_cells
        else 0.0,
        float(min(lows)) if lows else float("nan"),
        float(max(highs)) if highs else float("nan"))
