"""Comparing a DEM with a much coarser reference at the reference's resolution.

A gridded altimetry DEM (LOLA's and MOLA's gridded products) holds at each post the mean
of the ground over its cell (the shots binned and averaged; Smith et al. 2010, GRL 37,
L18204; Neumann et al. 2003, MOLA MEGDR), and shows nothing of the relief between its
posts.  Sampling such a reference at a fine DEM's cells (bilinearly), or a fine DEM at
the reference's posts, charges the DEM with the relief the reference misses; the
standard check averages the fine DEM over each reference cell first (GDAL's
``gdalwarp -r average`` onto the reference's grid) and differences the two at the
reference's posts.

* :func:`block_mean` — values at fine positions averaged over the coarse cells they
  fall in (pure, arrays in and out).
* :func:`block_average` — a raster on one grid averaged over the cells of a coarser
  grid (CRSs may differ: exact pyproj transformation).
* :func:`reference_at_blocks` — the reference where each block mean is compared.
* :func:`compare_at_reference_resolution` — the report beside the comparison grid's
  figures: the DEM block-averaged onto the reference's grid, minus the reference at its
  posts.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from demtool.compare.grids import Grid, resample_to_grid, sample_bilinear, source_pixels
from demtool.errors import ProcessingError
from demtool.logs import get_logger

__all__ = ["BlockMean", "block_average", "block_mean", "compare_at_reference_resolution",
           "reference_at_blocks", "resolution_ratio", "MIN_FILLED", "MIN_RATIO"]

log = get_logger(__name__)

#: a reference post coarser than this many DEM cells (metres over metres, per axis,
#: geometric mean) gets the comparison at its resolution: below 2 a post holds fewer
#: than 2 × 2 DEM cells and their mean is the bilinear sample within a cell's relief
MIN_RATIO = 2.0
#: share of a reference cell the DEM must measure for its mean to count (a majority: a
#: cell half outside the DEM or half in its holes is not the cell's mean)
MIN_FILLED = 0.5


class BlockMean(NamedTuple):
    """Fine values averaged over coarse cells (:func:`block_mean`, :func:`block_average`).

    Attributes
    ----------
    mean : (rows, columns) float64
        The mean, NaN where less than ``min_filled`` of the cell has values.
    filled : (rows, columns) float64
        The share of each cell with values (0 … 1, may exceed 1 by rounding).
    row, col : (rows, columns) float64
        The centroid of the averaged values in the coarse grid's array coordinates (the
        cell's centre when it is full; NaN where ``mean`` is): where a partly measured
        cell's mean is to be compared (the reference interpolated there).
    """

    mean: np.ndarray
    filled: np.ndarray
    row: np.ndarray
    col: np.ndarray


def block_mean(values: np.ndarray, rows: np.ndarray, cols: np.ndarray,
               shape: tuple[int, int], cells_per_post: float | np.ndarray, *,
               min_filled: float = MIN_FILLED) -> BlockMean:
    """The mean of fine values over each coarse cell they fall in.

    Parameters
    ----------
    values : (N,) float
        The fine raster's values (metres), NaN = no data.
    rows, cols : (N,) float
        Where they lie in the coarse grid, array coordinates (the centre of cell
        [r, c] at (r, c), so the cell spans r ± 0.5, c ± 0.5); NaN = nowhere.
    shape : (int, int)
        The coarse grid's (rows, columns).
    cells_per_post : float or (rows, columns) float
        How many fine cells one full coarse cell holds (its area over theirs).
    min_filled : float
        Least share of a coarse cell with values for its mean to count.

    Returns
    -------
    BlockMean
    """
    return _finish(*_bin(values, rows, cols, shape),
                   np.asarray(cells_per_post, dtype=np.float64), min_filled)


def _bin(values, rows, cols, shape) -> tuple[np.ndarray, ...]:
    """Sum, count and sums of rows and columns (``shape``) of the finite values in each
    coarse cell."""
    values = np.asarray(values, dtype=np.float64).ravel()
    rows = np.asarray(rows, dtype=np.float64).ravel()
    cols = np.asarray(cols, dtype=np.float64).ravel()
    height, width = shape
    with np.errstate(invalid="ignore"):
        r = np.floor(rows + 0.5)
        c = np.floor(cols + 0.5)
        use = np.isfinite(values) & (r >= 0) & (r < height) & (c >= 0) & (c < width)
    index = (r[use] * width + c[use]).astype(np.int64)
    size = height * width
    return (np.bincount(index, values[use], minlength=size).reshape(shape),
            np.bincount(index, minlength=size).reshape(shape).astype(np.float64),
            np.bincount(index, rows[use], minlength=size).reshape(shape),
            np.bincount(index, cols[use], minlength=size).reshape(shape))


def _finish(sums, count, row_sums, col_sums, cells_per_post, min_filled) -> BlockMean:
    """:class:`BlockMean` from :func:`_bin`'s sums."""
    with np.errstate(invalid="ignore", divide="ignore"):
        filled = count / cells_per_post
        keep = (count > 0) & (filled >= min_filled)
        return BlockMean(np.where(keep, sums / count, np.nan), filled,
                         np.where(keep, row_sums / count, np.nan),
                         np.where(keep, col_sums / count, np.nan))


def _cells_per_post(fine: Grid, coarse: Grid, window: tuple[int, int, int, int]
                    ) -> np.ndarray:
    """Fine cells per coarse cell over ``window`` of ``coarse``: the area of the
    parallelogram that one coarse cell's step along its row and its column spans in the
    fine grid's pixels (exact for affine grids, the local Jacobian where the CRSs
    differ)."""
    from affine import Affine

    base = source_pixels(fine, coarse, window)
    shifted = []
    for dx, dy in ((1.0, 0.0), (0.0, 1.0)):
        grid = Grid(coarse.shape, coarse.transform @ Affine.translation(dx, dy), coarse.crs)
        shifted.append(source_pixels(fine, grid, window))
    (r1, c1), (r2, c2) = shifted
    r0, c0 = base
    return np.abs((c1 - c0) * (r2 - r0) - (r1 - r0) * (c2 - c0))


def block_average(values: np.ndarray, fine: Grid, coarse: Grid, *,
                  min_filled: float = MIN_FILLED, rows_per_block: int = 512) -> BlockMean:
    """A raster averaged over the cells of a coarser grid (``gdalwarp -r average``; ISIS
    ``reduce algorithm=average validper=50``).

    Each fine cell counts wholly in the coarse cell its centre falls in (through the
    two transforms, or an exact pyproj transformation where the CRSs differ: as
    :func:`demtool.compare.grids.source_pixels`).

    Parameters
    ----------
    values : (H, W) float
        The raster on ``fine``, NaN = no data.
    fine, coarse : Grid
    min_filled : float
        Least share of a coarse cell with values for its mean to count
        (:func:`block_mean`).
    rows_per_block : int
        Fine rows transformed at a time (memory).

    Returns
    -------
    BlockMean
        On ``coarse``.
    """
    values = np.asarray(values, dtype=np.float64)
    height, width = fine.shape
    sums = [np.zeros(coarse.shape) for _ in range(4)]
    for start in range(0, height, rows_per_block):
        stop = min(height, start + rows_per_block)
        rows, cols = source_pixels(coarse, fine, (start, stop, 0, width))
        for total, part in zip(sums, _bin(values[start:stop], rows, cols, coarse.shape),
                               strict=True):
            total += part
    cells = np.full(coarse.shape, np.inf)  # untouched cells: nothing measured
    touched = np.nonzero(sums[1] > 0)
    if touched[0].size:
        r0, r1 = int(touched[0].min()), int(touched[0].max()) + 1
        c0, c1 = int(touched[1].min()), int(touched[1].max()) + 1
        cells[r0:r1, c0:c1] = _cells_per_post(fine, coarse, (r0, r1, c0, c1))
    return _finish(*sums, cells, min_filled)


def resolution_ratio(dem_grid: Grid, reference_grid: Grid) -> tuple[float, float]:
    """How many times coarser the reference's posts are than the DEM's cells, and the
    posts' spacing (metres; geometric mean of the two axes; a grid in degrees measured
    on its metric grid, :func:`demtool.compare.planetary.metric_grid`)."""
    from demtool.compare.planetary import metric_grid

    dem_metric, _ = metric_grid(dem_grid)
    coarse, _ = metric_grid(reference_grid)
    post = float(np.sqrt(np.prod(coarse.spacing)))
    return post / float(np.sqrt(np.prod(dem_metric.spacing))), post


def reference_at_blocks(reference: np.ndarray, block: BlockMean) -> np.ndarray:
    """The reference where each block mean is to be compared, metres.

    A partly measured cell's mean is that of its measured part, so the reference is read
    at that part's centroid (bilinearly; its post when the cell is full): a first-order
    correction, exact on a plane, of the slope across a cell on the DEM's edge.  The
    outermost posts are read at most at themselves (nothing lies beyond them).

    Parameters
    ----------
    reference : (rows, columns) float
        The coarse reference, metres, NaN = no data.
    block : BlockMean
        The fine DEM's means on the reference's grid.

    Returns
    -------
    (rows, columns) float64
        NaN where ``block.mean`` or the reference is.
    """
    out = np.full(block.mean.shape, np.nan)
    at = np.isfinite(block.row) & np.isfinite(block.col)
    out[at] = sample_bilinear(np.asarray(reference, dtype=np.float64),
                              np.clip(block.row[at], 0, out.shape[0] - 1),
                              np.clip(block.col[at], 0, out.shape[1] - 1))
    return out


def compare_at_reference_resolution(dem: np.ndarray, dem_grid: Grid, reference: np.ndarray,
                                    reference_grid: Grid, *, align: str = "nuth-kaab",
                                    slope_bins: Sequence[float] | None = None, seed: int = 0,
                                    min_ratio: float = MIN_RATIO) -> dict[str, Any] | None:
    """The comparison at a coarse reference's resolution: the DEM averaged over each
    reference cell minus the reference at its posts.

    Parameters
    ----------
    dem : (H, W) float
        The DEM on ``dem_grid``, metres, NaN = no data (masked cells NaN).
    dem_grid : Grid
    reference : (h, w) float
        The reference on ``reference_grid``, metres.
    reference_grid : Grid
        A grid in degrees is measured on its metric grid
        (:func:`demtool.compare.planetary.metric_grid`, the reference resampled there).
    align, slope_bins, seed
        As :func:`demtool.compare.compare_dems` (the alignment is fitted at this
        resolution; too few posts to fit leave it unaligned, with a warning).
    min_ratio : float
        The least ratio of the reference's post spacing to the DEM's (metres, geometric
        mean of the two axes) that calls for this comparison.

    Returns
    -------
    dict or None
        None when the reference is not ``min_ratio`` times coarser.  Otherwise
        ``what`` (one line saying what these figures are), ``posts`` (reference posts
        compared), ``dem_cells_per_post``, ``count``, ``mean``, ``median``, ``std``,
        ``rmse``, ``nmad``, ``le90``, ``min``, ``max``, ``shift``, ``alignment``,
        ``before_alignment`` and ``warnings`` of :func:`demtool.compare.compare_dems`,
        or ``error`` when no reference post is covered enough.
    """
    from demtool.compare.core import DEFAULT_SLOPE_BINS, compare_dems
    from demtool.compare.planetary import metric_grid

    ratio, post = resolution_ratio(dem_grid, reference_grid)
    if not ratio >= min_ratio:
        return None
    coarse, degrees = metric_grid(reference_grid)
    values = np.asarray(reference, dtype=np.float64)
    if degrees is not None:
        values = resample_to_grid(values, reference_grid, coarse)
    block = block_average(dem, dem_grid, coarse)
    at_posts = reference_at_blocks(values, block)
    what = (f"the DEM averaged over each reference cell ({ratio:.3g} x {ratio:.3g} DEM cells "
            f"a post, cells at least {MIN_FILLED:.0%} measured) minus the reference at its "
            f"posts ({post:.4g} m; at the measured part's centroid where a cell is partly "
            "measured); the top-level figures are on the comparison grid (grid.on), where "
            "one raster is interpolated at the other's cells")
    out: dict[str, Any] = {"what": what, "post_spacing_m": post,
                           "dem_cells_per_post": ratio ** 2,
                           "posts": int(np.sum(np.isfinite(block.mean)
                                               & np.isfinite(at_posts)))}
    try:
        comparison = compare_dems(block.mean, at_posts, spacing=coarse.spacing, align=align,
                                  slope_bins=slope_bins or DEFAULT_SLOPE_BINS, seed=seed)
    except ProcessingError as exc:
        out["error"] = str(exc)
        log.warning("at the reference's resolution: %s", exc)
        return out
    report = comparison.report
    out.update({k: report[k] for k in ("count", "mean", "median", "std", "rmse", "nmad",
                                       "le90", "min", "max", "shift", "alignment",
                                       "before_alignment", "warnings")})
    return out
