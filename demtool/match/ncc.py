"""Normalised cross-correlation along the rows of a rectified pair, and image pyramids.

For a template of the left image centred on pixel (r, c), :func:`ncc_search` tries
every integer disparity ``d`` of a per-template range ``[d_low, d_high]`` — the
template is compared with the right window centred on (r, c − d) — keeps the
disparity of the highest normalised cross-correlation coefficient and refines it
to sub-pixel precision with a parabola through the peak and its two neighbours.
Templates or windows that touch nodata are not compared.

:func:`build_pyramid` makes the Gaussian pyramid (``cv2.pyrDown``: 5 × 5 binomial
filter and decimation by 2) in which the dense matcher works coarse to fine; level
``k`` pixel (r, c) is full-resolution pixel (2ᵏ r, 2ᵏ c), and disparities scale by 2ᵏ.

References
----------
Burt, P., Adelson, E. (1983). The Laplacian pyramid as a compact image code.
    IEEE Trans. Communications 31(4), 532-540.
Lewis, J. P. (1995). Fast normalized cross-correlation. Vision Interface, 120-123.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from demtool.tiling.rows import on_row_parts


class NCCResult(NamedTuple):
    """Best NCC disparity of N templates.

    Attributes
    ----------
    disparity : (N,) float64
        Sub-pixel disparity (pixels, ``x_right = x_left − d``) at the correlation
        peak; NaN where no candidate could be compared.
    correlation : (N,) float64
        Peak correlation coefficient (−1 … 1); NaN where no candidate.
    """

    disparity: np.ndarray
    correlation: np.ndarray


def integral_invalid(valid: np.ndarray) -> np.ndarray:
    """Summed-area table of the invalid pixels, (H + 1, W + 1) int32 (0 row/column first)."""
    invalid = (~np.asarray(valid, dtype=bool)).astype(np.int32)
    table = np.zeros((invalid.shape[0] + 1, invalid.shape[1] + 1), dtype=np.int32)
    table[1:, 1:] = invalid.cumsum(0).cumsum(1)
    return table


@njit(cache=True, inline="always")
def _window_clean(table: np.ndarray, row: int, col: int, half: int) -> bool:
    height = table.shape[0] - 1
    width = table.shape[1] - 1
    r0 = row - half
    c0 = col - half
    r1 = row + half + 1
    c1 = col + half + 1
    if r0 < 0 or c0 < 0 or r1 > height or c1 > width:
        return False
    return table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0] == 0


@njit(cache=True, nogil=True, error_model="numpy")
def _ncc_batch(left, left_table, right, right_table, rows, cols, d_low, d_high, half,
               out_d, out_c, start, stop):
    """The NCC search of templates ``start … stop − 1`` (see :func:`ncc_search`); run
    over row parts by :func:`demtool.tiling.rows.on_row_parts`."""
    n = (2 * half + 1) ** 2
    for k in range(start, stop):
        row = rows[k]
        col = cols[k]
        out_d[k] = np.nan
        out_c[k] = np.nan
        if not _window_clean(left_table, row, col, half):
            continue
        sf = 0.0
        sff = 0.0
        for v in range(-half, half + 1):
            for u in range(-half, half + 1):
                f = left[row + v, col + u]
                sf += f
                sff += f * f
        var_f = sff - sf * sf / n
        if var_f <= 1e-12 * max(sff, 1.0):
            continue
        lo = d_low[k]
        hi = d_high[k]
        if hi < lo:
            continue
        count = hi - lo + 1
        scores = np.full(count, np.nan)
        best = -2.0
        best_i = -1
        for i in range(count):
            d = lo + i
            cr = col - d
            if not _window_clean(right_table, row, cr, half):
                continue
            sg = 0.0
            sgg = 0.0
            sfg = 0.0
            for v in range(-half, half + 1):
                for u in range(-half, half + 1):
                    g = right[row + v, cr + u]
                    sg += g
                    sgg += g * g
                    sfg += left[row + v, col + u] * g
            var_g = sgg - sg * sg / n
            if var_g <= 1e-12 * max(sgg, 1.0):
                continue
            score = (sfg - sf * sg / n) / np.sqrt(var_f * var_g)
            scores[i] = score
            if score > best:
                best = score
                best_i = i
        if best_i < 0:
            continue
        offset = 0.0
        if 0 < best_i < count - 1:
            s_minus = scores[best_i - 1]
            s_plus = scores[best_i + 1]
            if np.isfinite(s_minus) and np.isfinite(s_plus):
                curvature = s_minus - 2.0 * best + s_plus
                if curvature < 0.0:
                    offset = 0.5 * (s_minus - s_plus) / curvature
                    offset = min(0.5, max(-0.5, offset))
        out_d[k] = lo + best_i + offset
        out_c[k] = best


def ncc_search(left: np.ndarray, right: np.ndarray, rows: np.ndarray, cols: np.ndarray,
               d_low: np.ndarray, d_high: np.ndarray, *, template: int,
               left_valid: np.ndarray | None = None,
               right_valid: np.ndarray | None = None) -> NCCResult:
    """Best integer disparity (with parabola sub-pixel) of each template along its row.

    Parameters
    ----------
    left, right : (H, W) float
        Rectified grey images; NaN = nodata.  Not modified.
    rows, cols : (N,) int
        Template centres in the left image.
    d_low, d_high : (N,) int
        Inclusive disparity search range of each template (``x_right = x_left − d``).
    template : int
        Template size in pixels (odd).
    left_valid, right_valid : (H, W) bool, optional
        True where the pixel may be used (default: finite).

    Returns
    -------
    NCCResult
        Peak disparity and correlation; NaN where the template touches nodata or the
        border, is flat, or no candidate window is usable.
    """
    half = int(template) // 2
    left = np.asarray(left, dtype=np.float64)
    right = np.asarray(right, dtype=np.float64)
    left_ok = np.isfinite(left) if left_valid is None else (left_valid & np.isfinite(left))
    right_ok = np.isfinite(right) if right_valid is None else (right_valid & np.isfinite(right))
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    out_d = np.empty(rows.shape[0])
    out_c = np.empty(rows.shape[0])
    if rows.shape[0]:
        args = (np.where(left_ok, left, 0.0), integral_invalid(left_ok),
                np.where(right_ok, right, 0.0), integral_invalid(right_ok), rows,
                np.ascontiguousarray(cols, dtype=np.int64),
                np.ascontiguousarray(d_low, dtype=np.int64),
                np.ascontiguousarray(d_high, dtype=np.int64), half, out_d, out_c)
        on_row_parts(lambda start, stop: _ncc_batch(*args, start, stop), rows.shape[0])
    return NCCResult(out_d, out_c)


def build_pyramid(image: np.ndarray, levels: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Gaussian pyramid of an image with nodata.

    Parameters
    ----------
    image : (H, W) float
        Grey image; NaN = nodata.
    levels : int
        Number of levels (1 = the image alone).

    Returns
    -------
    list of (image, valid)
        Level 0 first: ``image`` float32 (nodata filled with the mean of the valid
        pixels), ``valid`` bool.  A coarse pixel is valid only when every full-level
        pixel under its 5 × 5 filter footprint is.
    """
    import cv2
    from scipy import ndimage

    valid = np.isfinite(image)
    fill = float(np.mean(image[valid])) if valid.any() else 0.0
    current = np.where(valid, image, fill).astype(np.float32)
    pyramid = [(current, valid)]
    for _ in range(1, levels):
        coarse = cv2.pyrDown(current)
        eroded = ndimage.minimum_filter(valid.astype(np.uint8), size=5, mode="constant",
                                        cval=0).astype(bool)
        coarse_valid = eroded[::2, ::2][: coarse.shape[0], : coarse.shape[1]]
        current, valid = coarse, coarse_valid
        pyramid.append((current, valid))
    return pyramid
