"""The pure core of ``demtool fuse``: border weights, per-cell robust combination, shifts.

Several DEMs of one area, already on one grid, are combined cell by cell, as ASP's
``dem_mosaic`` does for its blending and ``--median`` / ``--stddev`` / ``--count``
outputs and as s2p fuses the pairwise DSMs of a triplet:

1. each DEM's **border weight** (:func:`border_weights`): the distance of a cell to the
   nearest cell the DEM does not cover, capped at ``blend_px`` and raised to
   ``exponent`` (ASP ``dem_mosaic``: weights that grow with the distance to the DEM's
   boundary, ``--weights-exponent`` 2 by default), so a DEM's edge fades out instead of
   leaving a step where it ends;
2. per cell, the **outlier rejection**: values farther from the cell's median than
   ``outlier_k`` × its NMAD (normalised median absolute deviation, 1.4826 MAD: Höhle &
   Höhle 2009, eq. 5) are dropped; the value nearest the median always stays, so a cell
   that some DEM covers is never emptied;
3. the **combination** of the kept values with weights ``w = border / σ²`` (σ the DEM's
   error raster, e.g. ``dem --error-out``'s median ray gap; without error rasters
   ``w = border``): the weighted **median** (``method="median"``), the weighted
   **mean** (``method="mean"``), or (``method="huber"``, no rejection in step 2) Huber's
   M-estimate of location (Huber 1964; IRLS with c = 1.345, 95 % efficiency under
   Gaussian errors: Holland & Welsch 1977), each value weighted ``w`` times
   ``min(1, c s / |h − μ|)``, with the scale ``s`` the larger of the cell's NMAD and the
   stack's (:func:`stack_nmad`: the spread of values against their cell's median over
   the whole overlap, so that a cell whose few values agree by chance does not treat a
   normal one as an outlier) — the influence of a blunder is bounded instead of cut;
4. the **count** of kept values, the **spread** (their NMAD, NaN where fewer than two)
   and the **combined error**: with error rasters the standard error of the weighted
   mean, ``sqrt(Σ w² σ²) / Σ w`` (independent errors), times √(π/2) = 1.2533 for the
   median (its asymptotic efficiency relative to the mean for Gaussian errors); without
   them the spread over √count (NaN where count < 2).

Everything here is cell-local except the border weights, whose cap makes them depend
only on cells within ``blend_px``: a tile computed on its core plus a margin of
``blend_px + 1`` cells gives the untiled numbers exactly (:mod:`demtool.fuse.tiled`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from demtool.errors import ProcessingError

__all__ = ["METHODS", "NMAD_SCALE", "FuseResult", "border_weights", "combine",
           "consensus_nmad", "estimate_shift", "nmad_against_others",
           "stack_nmad"]

METHODS = ("median", "mean", "huber")
HUBER_C = 1.345  # Huber's tuning constant: 95 % efficiency for Gaussian errors
HUBER_ITERATIONS = 10
NMAD_SCALE = 1.4826  # MAD → σ of a normal distribution
MEDIAN_EFFICIENCY = math.sqrt(math.pi / 2.0)  # σ(median) / σ(mean), Gaussian errors
MIN_COMMON_CELLS = 50  # common cells a co-registration needs, at least


class FuseResult(NamedTuple):
    """The fused rasters, all ``(H, W)`` float32 on the common grid.

    Attributes
    ----------
    dem : heights, metres, NaN where no DEM has a value
    count : number of DEMs combined in each cell (0 where none)
    spread : NMAD of the kept heights, metres (NaN where count < 2)
    error : combined one-sigma error, metres (see the module docstring)
    """

    dem: np.ndarray
    count: np.ndarray
    spread: np.ndarray
    error: np.ndarray


def border_weights(valid: np.ndarray, *, blend_px: float, exponent: float = 2.0,
                   gap_px: float = 0.0) -> np.ndarray:
    """Weights that fall off towards the border of a DEM's valid area.

    Parameters
    ----------
    valid : (H, W) bool
        True where the DEM has a value.
    blend_px : float
        Blending length, cells: a cell this far (or farther) from the DEM's border has
        weight 1.  0 turns blending off (weight 1 on every valid cell).
    exponent : float
        The capped distance ratio is raised to this power (ASP ``dem_mosaic``
        ``--weights-exponent``, default 2).
    gap_px : float
        Gaps (holes, unmatched patches) that a closing by a disk of this radius, cells,
        bridges — about ``2 gap_px`` wide — are not borders: the weights fall off towards
        the DEM's footprint, not around each small hole, which would otherwise take
        most of the DEM's weight where matching leaves scattered holes.  0: every
        invalid cell is a border.

    Returns
    -------
    (H, W) float64
        ``(min(d, blend_px) / blend_px) ** exponent`` with ``d`` the Euclidean distance
        (cells, scipy's exact EDT: :func:`_distances`) from the cell's centre to the
        nearest cell outside the DEM's footprint (its valid cells closed by ``gap_px``);
        a cell next to the border has d = 1, so every valid cell weighs > 0; 0 on invalid
        cells.  The array's own edge is not a border: a DEM is only faded where its data
        ends.  The value of a cell depends only on cells within ``blend_px + 2 gap_px``
        of it.
    """
    valid = np.asarray(valid, dtype=bool)
    if blend_px <= 0 or valid.all():
        return valid.astype(np.float64)
    if not valid.any():
        return np.zeros(valid.shape)
    footprint = valid
    if gap_px > 0:  # closing by a disk of radius gap_px, through two distance transforms
        grown = _distances(~valid) <= gap_px
        if grown.all():
            return valid.astype(np.float64)
        footprint = valid | (_distances(grown) > gap_px)
    if footprint.all():
        return valid.astype(np.float64)
    distance = _distances(footprint)
    return np.where(valid, (np.minimum(distance, blend_px) / blend_px) ** exponent, 0.0)


def _distances(foreground: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.distance_transform_edt(foreground)`` (which needs a background
    cell somewhere), to the bit, compiled: :func:`demtool.fuse.kernels.distances_to_background`
    (3.3 times less CPU on a 2048² DEM with holes)."""
    from demtool.fuse.kernels import distances_to_background

    out = np.empty(foreground.shape)
    distances_to_background(np.ascontiguousarray(foreground, dtype=bool), out)
    return out


def _nan_median(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Median along axis 0 of the valid entries (NaN where none), without warnings.

    ``values`` (N, ...) with finite values where ``valid``.  The numbers of
    ``np.nanmedian`` (the middle valid value, or ``(low + high) / 2`` of the middle two),
    to the bit but for the sign of a zero median where both −0 and +0 are among the
    values (numpy's sort does not order them either; the median enters fuse's outputs
    only through ``|h − median|``); one compiled pass over the cells
    (:func:`demtool.fuse.kernels.nan_median_cells`) instead of a sort of the stack.
    """
    shape = np.shape(values)[1:]
    if len(values) == 0:
        return np.full(shape, np.nan)
    from demtool.fuse.kernels import nan_median_cells

    count = len(values)
    out = np.empty(int(np.prod(shape, dtype=np.int64)))
    nan_median_cells(np.ascontiguousarray(values, dtype=np.float64).reshape(count, -1),
                     np.ascontiguousarray(valid, dtype=bool).reshape(count, -1), out)
    return out.reshape(shape)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted median along axis 0 (weights 0 = absent; NaN where all are 0).

    The smallest value whose cumulative weight reaches half the total; where the
    cumulative weight equals half the total exactly, the mean of that value and the
    next (so two equal weights give their mean, as the ordinary median does).
    """
    keyed = np.where(weights > 0, values, np.inf)
    order = np.argsort(keyed, axis=0, kind="stable")
    v = np.take_along_axis(keyed, order, axis=0)
    w = np.take_along_axis(weights, order, axis=0)
    cumulative = np.cumsum(w, axis=0)
    total = cumulative[-1]
    half = 0.5 * total
    tol = 1e-12 * np.maximum(total, 1e-300)
    index = np.argmax(cumulative >= half - tol, axis=0)
    first = np.take_along_axis(v, index[None], axis=0)[0]
    exact = np.abs(np.take_along_axis(cumulative, index[None], axis=0)[0] - half) <= tol
    following = np.minimum(index + 1, len(values) - 1)
    second = np.take_along_axis(v, following[None], axis=0)[0]
    second = np.where(np.isfinite(second), second, first)
    out = np.where(exact, 0.5 * (first + second), first)
    return np.where(total > 0, out, np.nan)


def _huber(values: np.ndarray, weights: np.ndarray, start: np.ndarray, scale: np.ndarray
           ) -> np.ndarray:
    """Per-cell Huber M-estimate by iteratively reweighted least squares.

    ``values`` (N, H, W) with ``weights`` (N, H, W, 0 = absent), starting from ``start``
    (H, W) with the scale ``scale`` (H, W, > 0).  Returns the final weights (prior
    weights times Huber's ``min(1, c s / |r|)``); the estimate is their weighted mean.
    Each cell's :data:`HUBER_ITERATIONS` steps (fewer where the estimate stops moving)
    run in a compiled loop over the cells (:func:`demtool.fuse.kernels.huber_rows`).
    """
    from demtool.fuse.kernels import huber_rows

    values = np.ascontiguousarray(values, dtype=np.float64)
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    out = np.empty_like(weights)
    huber_rows(values, weights, np.ascontiguousarray(start, dtype=np.float64),
               np.array(np.broadcast_to(scale, start.shape), dtype=np.float64),
               HUBER_C, HUBER_ITERATIONS, out)
    return out


def combine(values: np.ndarray, weights: np.ndarray, errors: np.ndarray | None = None, *,
            method: str = "mean", outlier_k: float = 3.0, min_error: float = 0.01,
            scale_floor: float = 0.0) -> FuseResult:
    """Combine co-registered DEMs on one grid, cell by cell (see the module docstring).

    Parameters
    ----------
    values : (N, H, W) float array, metres, NaN = no value
        The N DEMs' heights on the common grid.  Not modified.
    weights : (N, H, W) float array, >= 0
        Border weights (:func:`border_weights`); 0 where a DEM has no value.
    errors : (N, H, W) float array, metres, optional
        Each DEM's one-sigma error (e.g. the triangulation's ray gap); NaN or
        non-positive entries are raised to ``min_error``.  Needed by ``method="median"``.
    method : {"median", "mean", "huber"}
        Weighted median, or weighted mean of the values kept by the outlier rejection,
        or Huber's M-estimate of every value (no rejection).
    outlier_k : float
        Rejection threshold in NMADs of the cell's values (>= 1; not used by huber).
    min_error : float
        Floor of the error rasters, metres (a zero ray gap is not infinite precision).
    scale_floor : float
        Huber: the smallest scale, metres (:func:`stack_nmad` of the whole stack; 0: the
        cell's NMAD alone, floored at 1 mm).

    Returns
    -------
    FuseResult

    Raises
    ------
    ValueError
        An unknown method, ``median`` without errors, mismatched shapes, ``outlier_k`` < 1.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: should be one of {', '.join(METHODS)}")
    if method == "median" and errors is None:
        raise ValueError("method 'median' weighs each DEM by its error raster: give errors")
    if outlier_k < 1:
        raise ValueError(f"outlier_k must be >= 1, got {outlier_k}")
    values = np.asarray(values, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    if values.ndim != 3 or weights.shape != values.shape:
        raise ValueError(f"values and weights must be (N, H, W) of one shape, got "
                         f"{values.shape} and {weights.shape}")
    valid = np.isfinite(values) & (weights > 0)
    median = _nan_median(values, valid)
    residual = np.abs(values - median)
    mad = _nan_median(residual, valid)
    keep = valid if method == "huber" else \
        valid & (residual <= outlier_k * NMAD_SCALE * mad + 1e-9)
    count = keep.sum(axis=0)
    w = np.where(keep, weights, 0.0)
    sigma = None
    if errors is not None:
        errors = np.asarray(errors, dtype=np.float64)
        if errors.shape != values.shape:
            raise ValueError(f"errors must have the values' shape {values.shape}, got "
                             f"{errors.shape}")
        sigma = np.where(np.isfinite(errors) & (errors > min_error), errors, min_error)
        w = w / sigma**2
    total = w.sum(axis=0)
    has = total > 0
    safe_total = np.where(has, total, 1.0)
    if method == "huber":
        scale = np.maximum(np.maximum(NMAD_SCALE * np.nan_to_num(mad), scale_floor), 1e-3)
        w = _huber(values, w, median, scale)
        total = w.sum(axis=0)
        has = total > 0
        safe_total = np.where(has, total, 1.0)
    if method == "median":
        dem = _weighted_median(np.where(keep, values, 0.0), w)
    else:
        dem = np.where(has, (w * np.where(keep, values, 0.0)).sum(axis=0) / safe_total, np.nan)
    if method == "huber" or np.array_equal(keep, valid):  # nothing rejected: the same
        kept_mad = mad  # median and MAD as above (huber keeps every valid value)
    else:
        kept_median = _nan_median(values, keep)
        kept_mad = _nan_median(np.abs(values - kept_median), keep)
    spread = np.where(count >= 2, NMAD_SCALE * kept_mad, np.nan)
    if sigma is not None:
        error = np.sqrt((w**2 * sigma**2).sum(axis=0)) / safe_total
        if method == "median":
            error = error * MEDIAN_EFFICIENCY
        error = np.where(has, error, np.nan)
    else:
        error = spread / np.sqrt(np.maximum(count, 1))
    return FuseResult(dem.astype(np.float32), count.astype(np.float32),
                      spread.astype(np.float32), error.astype(np.float32))


def estimate_shift(dem: np.ndarray, reference: np.ndarray, *, method: str = "nuth-kaab",
                   spacing: tuple[float, float] = (1.0, 1.0), label: str = "DEM"
                   ) -> dict:
    """The shift that aligns ``dem`` with ``reference`` (compare's co-registration).

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid, on one grid
    method : str
        One of :data:`demtool.compare.align.ALIGN_METHODS` (``none``: no shift).
    spacing : (float, float)
        Cell size (x, y), metres.
    label : str
        The DEM's name, for messages.

    Returns
    -------
    dict
        The :class:`demtool.compare.align.Alignment` as a dict: ``shift`` (``dx_px``,
        ``dy_px``: x right, y down, grid cells; ``dz`` metres — added to the DEM, it
        aligns it), ``shift_uncertainty``, ``steps``, ``warnings``, and
        ``common_cells``.

    Raises
    ------
    ProcessingError
        Fewer than :data:`MIN_COMMON_CELLS` cells where both have a value.
    """
    from demtool.compare.align import coregister

    common = int(np.count_nonzero(np.isfinite(dem) & np.isfinite(reference)))
    if common < MIN_COMMON_CELLS:
        raise ProcessingError(f"{label}: no common overlap with the reference ({common} "
                              f"cells where both have heights, {MIN_COMMON_CELLS} needed): "
                              "fuse DEMs of one area")
    if method == "none":
        out = {"method": "none", "shift": {"dx_px": 0.0, "dy_px": 0.0, "dz": 0.0},
               "shift_uncertainty": {"dx_px": 0.0, "dy_px": 0.0, "dz": 0.0},
               "steps": [], "warnings": []}
    else:
        _, alignment = coregister(dem, reference, method=method, spacing=spacing)
        out = alignment.as_dict()
    out["common_cells"] = common
    return out


def stack_nmad(values: np.ndarray) -> float:
    """The spread of a stack: NMAD of every value's residual to its cell's median.

    Parameters
    ----------
    values : (N, H, W) float array, metres, NaN = no value

    Returns
    -------
    float
        ``1.4826 median |h_i − median_j h_j|`` over the cells with two values or more
        (metres); 0 where there is no such cell.
    """
    values = np.asarray(values, dtype=np.float64)
    valid = np.isfinite(values)
    shared = valid.sum(axis=0) >= 2
    if not shared.any():
        return 0.0
    median = _nan_median(values[:, shared], valid[:, shared])
    residual = np.abs(values[:, shared] - median)[valid[:, shared]]
    return float(NMAD_SCALE * np.median(residual))


def consensus_nmad(values: np.ndarray, mapper=None) -> np.ndarray:
    """Each DEM's NMAD against the median of the others, on common cells.

    Parameters
    ----------
    values : (N, H, W) float array, metres, NaN = no value (N >= 2)
    mapper : callable, optional
        ``mapper(function, items) -> list``, the DEMs' computations (independent) mapped
        over, e.g. on threads (:func:`demtool.fuse.tiled.on_threads`); default in turn.

    Returns
    -------
    (N,) float64
        :func:`nmad_against_others` of each DEM; NaN where there is no common cell.
    """
    values = np.asarray(values, dtype=np.float64)
    valid = np.isfinite(values)
    indices = range(len(values))

    def one(i: int) -> float:
        return nmad_against_others(values, i, valid)

    return np.array(mapper(one, indices) if mapper else [one(i) for i in indices],
                    dtype=np.float64)


def nmad_against_others(values: np.ndarray, i: int, valid: np.ndarray | None = None
                        ) -> float:
    """DEM ``i``'s NMAD against the median of the others, on common cells.

    Parameters
    ----------
    values : (N, H, W) float64 array, metres, NaN = no value (N >= 2)
    i : int
        The DEM.
    valid : (N, H, W) bool, optional
        ``np.isfinite(values)``, when the caller has it.

    Returns
    -------
    float
        ``1.4826 median |h_i − median_{j≠i} h_j − their median|`` over the cells where
        DEM i and some other DEM have a value (metres); NaN where there is no such cell.
    """
    valid = np.isfinite(values) if valid is None else valid
    others = np.delete(np.arange(len(values)), i)
    consensus = _nan_median(values[others], valid[others])
    diff = values[i] - consensus
    diff = diff[np.isfinite(diff)]
    if not diff.size:
        return np.nan
    return NMAD_SCALE * np.median(np.abs(diff - np.median(diff)))
