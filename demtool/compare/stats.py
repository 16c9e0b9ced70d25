"""Error statistics of a DEM difference: global, per slope class, completeness."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from demtool.imaging.robust import nmad

__all__ = [
    "STAT_KEYS",
    "completeness",
    "difference_statistics",
    "slope_class_statistics",
    "slope_degrees",
]

STAT_KEYS = ("count", "mean", "median", "std", "rmse", "nmad", "le90", "min", "max")


def difference_statistics(difference: np.ndarray, mask: np.ndarray | None = None
                          ) -> dict[str, Any]:
    """Summary statistics of a height difference (DEM − reference).

    Parameters
    ----------
    difference : float array, metres, NaN = no common value
    mask : bool array of the same shape, optional
        True on pixels to include.

    Returns
    -------
    dict
        ``count`` (int) and, in metres, ``mean``, ``median``, ``std`` (population),
        ``rmse``, ``nmad`` = 1.4826 · median(|x − median(x)|) (Höhle & Höhle 2009,
        ISPRS J. 64(4), eq. 4), ``le90`` = 90th percentile of |x| (linear error at 90 %
        confidence, empirical), ``min``, ``max``.  Values are NaN when count is 0.
    """
    values = np.asarray(difference, dtype=np.float64)
    keep = np.isfinite(values)
    if mask is not None:
        keep &= mask
    x = values[keep]
    if x.size == 0:
        return {"count": 0, **{k: float("nan") for k in STAT_KEYS[1:]}}
    # one scratch array for the order statistics and squares, overwritten in turn (the
    # same numbers as a new array each; on a 4096² grid each is 128 MB of fresh pages)
    scratch = np.empty_like(x)
    np.copyto(scratch, x)
    median = float(np.median(scratch, overwrite_input=True))
    np.multiply(x, x, out=scratch)
    rmse = float(np.sqrt(np.mean(scratch)))
    spread = nmad(x, median=median, scratch=scratch)
    np.abs(x, out=scratch)
    le90 = float(np.percentile(scratch, 90, overwrite_input=True))
    return {
        "count": int(x.size),
        "mean": float(x.mean()),
        "median": median,
        "std": float(x.std()),
        "rmse": rmse,
        "nmad": spread,
        "le90": le90,
        "min": float(x.min()),
        "max": float(x.max()),
    }


def slope_degrees(dem: np.ndarray, spacing: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Slope of a DEM, degrees, from central differences (NaN at holes and their rims).

    Parameters
    ----------
    dem : (H, W) float array, metres, NaN = invalid
    spacing : (float, float)
        Pixel size (x, y), metres.
    """
    grad_row, grad_col = np.gradient(np.asarray(dem, dtype=np.float64))
    # in place: the same numbers without four more grid-sized arrays
    np.divide(grad_col, spacing[0], out=grad_col)
    np.divide(grad_row, spacing[1], out=grad_row)
    slope = np.hypot(grad_col, grad_row, out=grad_col)
    np.arctan(slope, out=slope)
    return np.degrees(slope, out=slope)


def slope_class_statistics(difference: np.ndarray, slope: np.ndarray,
                           bins: Sequence[float], mask: np.ndarray | None = None
                           ) -> list[dict[str, Any]]:
    """Statistics of ``difference`` in each slope class ``[bins[i], bins[i + 1])``.

    The last class includes its upper edge.  Returns one dict per class with
    ``slope_min_deg``, ``slope_max_deg`` and the keys of :func:`difference_statistics`.
    """
    edges = np.asarray(bins, dtype=np.float64)
    classes = []
    for index, (low, high) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        with np.errstate(invalid="ignore"):
            upper = slope <= high if index == len(edges) - 2 else slope < high
            in_class = (slope >= low) & upper
        if mask is not None:
            in_class &= mask
        classes.append({"slope_min_deg": float(low), "slope_max_deg": float(high),
                        **difference_statistics(difference, in_class)})
    return classes


def completeness(dem: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None
                 ) -> tuple[float, np.ndarray]:
    """Share of the reference's valid pixels where the DEM has a value.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, NaN = invalid, on one grid
    mask : (H, W) bool, optional
        Only pixels where True count.

    Returns
    -------
    percent : float
        100 · #(DEM valid ∧ reference valid) / #(reference valid), within the mask;
        NaN when the reference has no valid pixel there.
    coverage : (H, W) float32
        1 where the DEM has a value, 0 where it lacks one, NaN outside the reference
        (or the mask): the completeness map.
    """
    considered = np.isfinite(reference)
    if mask is not None:
        considered &= mask
    has_value = np.isfinite(dem)
    coverage = np.where(considered, has_value.astype(np.float32), np.float32(np.nan))
    total = int(considered.sum())
    percent = 100.0 * float((has_value & considered).sum()) / total if total else float("nan")
    return percent, coverage.astype(np.float32)
