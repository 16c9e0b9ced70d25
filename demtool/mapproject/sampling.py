"""Resampling kernels of ``demtool mapproject``: the image (bicubic) and the DEM (bilinear).

Split from :mod:`demtool.mapproject.core` (which re-exports the public names): Keys' cubic
convolution of the image at CSM image coordinates, the image window a map tile's samples
touch, and the NaN-propagating bilinear interpolation of the surface heights.

Reference: Keys, R. (1981), Cubic convolution interpolation for digital image processing,
IEEE Trans. ASSP 29(6), 1153-1160 (eq. 15, a = −0.5, GDAL's ``cubic``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["bicubic_sample", "bilinear_heights", "image_window", "resample_tile"]

@njit(cache=True, nogil=True)
def _keys(t):
    """Keys' cubic convolution kernel, a = −0.5 (Keys 1981, eq. 15)."""
    t = abs(t)
    if t <= 1.0:
        return (1.5 * t - 2.5) * t * t + 1.0
    if t < 2.0:
        return ((-0.5 * t + 2.5) * t - 4.0) * t + 2.0
    return 0.0


@njit(cache=True, nogil=True)
def _bicubic_at(image, r, c):
    """Keys bicubic convolution of ``image`` at fractional (row, col), edges clamped."""
    h, w = image.shape
    ri = int(math.floor(r))
    ci = int(math.floor(c))
    fr = r - ri
    fc = c - ci
    acc = 0.0
    for a in range(-1, 3):
        wr = _keys(fr - a)
        rr = min(max(ri + a, 0), h - 1)
        for b in range(-1, 3):
            wc = _keys(fc - b)
            cc = min(max(ci + b, 0), w - 1)
            acc += wr * wc * image[rr, cc]
    return acc


@njit(cache=True, parallel=True, nogil=True)
def _bicubic(image, row, col, out):
    n = row.shape[0]
    for p in prange(n):
        r = row[p]
        c = col[p]
        if not (math.isfinite(r) and math.isfinite(c)):
            out[p] = np.nan
            continue
        out[p] = _bicubic_at(image, r, c)


def bicubic_sample(image: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Bicubic convolution (Keys, a = −0.5) of an image at fractional array positions.

    Parameters
    ----------
    image : (H, W) float
        NaN = nodata (any NaN among the 4 × 4 neighbours gives NaN).
    row, col : arrays of one shape S, float
        Array coordinates (the centre of pixel [r, c] is at (r, c)); neighbours beyond
        the array repeat its edge; NaN positions give NaN.

    Returns
    -------
    S float32
    """
    row = np.asarray(row, dtype=np.float64)
    col = np.asarray(col, dtype=np.float64)
    out = np.empty(row.size, dtype=np.float64)
    _bicubic(np.ascontiguousarray(image, dtype=np.float32), row.ravel(), col.ravel(), out)
    return out.reshape(row.shape).astype(np.float32)


@njit(cache=True, nogil=True)
def _on_image_bounds(line, sample, lines, samples):
    lo_r = np.inf
    hi_r = -np.inf
    lo_c = np.inf
    hi_c = -np.inf
    for p in range(line.size):
        ln = line.flat[p]
        sm = sample.flat[p]
        if ln >= 0 and ln <= lines and sm >= 0 and sm <= samples:
            lo_r = min(lo_r, ln)
            hi_r = max(hi_r, ln)
            lo_c = min(lo_c, sm)
            hi_c = max(hi_c, sm)
    return lo_r, hi_r, lo_c, hi_c


def image_window(line: np.ndarray, sample: np.ndarray, lines: int, samples: int,
                 margin: int = 2) -> tuple[int, int, int, int] | None:
    """Image rows/columns ``(row0, row1, col0, col1)`` a tile's bicubic samples touch.

    ``None`` when no coordinate falls on the image.
    """
    lo_r, hi_r, lo_c, hi_c = _on_image_bounds(np.ascontiguousarray(line, dtype=np.float64),
                                              np.ascontiguousarray(sample, dtype=np.float64),
                                              float(lines), float(samples))
    if not np.isfinite(lo_r):
        return None
    return (max(int(math.floor(lo_r - 0.5)) - margin, 0),
            min(int(math.floor(hi_r - 0.5)) + margin + 1, lines),
            max(int(math.floor(lo_c - 0.5)) - margin, 0),
            min(int(math.floor(hi_c - 0.5)) + margin + 1, samples))


@njit(cache=True, parallel=True, nogil=True)
def _bicubic_csm(image, row0, col0, line, sample, lines, samples, out):
    """:func:`_bicubic` at CSM coordinates of a window starting at (row0, col0); NaN off
    the full image [0, lines] × [0, samples]."""
    for p in prange(line.shape[0]):
        ln = line[p]
        sm = sample[p]
        if not (ln >= 0 and ln <= lines and sm >= 0 and sm <= samples):
            out[p] = np.nan
            continue
        r = ln - 0.5 - row0
        c = sm - 0.5 - col0
        out[p] = _bicubic_at(image, r, c)


def resample_tile(image: np.ndarray, offset: tuple[int, int], line: np.ndarray,
                  sample: np.ndarray, lines: int, samples: int) -> np.ndarray:
    """Orthoimage values of a tile from a window of the image.

    Parameters
    ----------
    image : (h, w) float32
        The image rows ``offset[0]…`` and columns ``offset[1]…`` (NaN = nodata).
    offset : (row0, col0)
        Where the window starts in the full image, pixels.
    line, sample : S float
        CSM image coordinates of the tile's cells (first pixel centre at 0.5).
    lines, samples : int
        Full image size; cells outside [0, lines] × [0, samples] are NaN.

    Returns
    -------
    S float32, NaN where not seen.
    """
    line = np.asarray(line, dtype=np.float64)
    out = np.empty(line.size, dtype=np.float64)
    _bicubic_csm(np.ascontiguousarray(image, dtype=np.float32), float(offset[0]),
                 float(offset[1]), np.ascontiguousarray(line).ravel(),
                 np.ascontiguousarray(sample, dtype=np.float64).ravel(), float(lines),
                 float(samples), out)
    return out.reshape(line.shape).astype(np.float32)


@njit(cache=True, parallel=True, nogil=True)
def _bilinear(dem, row, col, out):
    h, w = dem.shape
    for p in prange(row.shape[0]):
        r = row[p]
        c = col[p]
        if not (r >= -0.5 and r <= h - 0.5 and c >= -0.5 and c <= w - 0.5):
            out[p] = np.nan
            continue
        r = min(max(r, 0.0), h - 1.0)
        c = min(max(c, 0.0), w - 1.0)
        r0 = min(int(r), max(h - 2, 0))
        c0 = min(int(c), max(w - 2, 0))
        r1 = min(r0 + 1, h - 1)
        c1 = min(c0 + 1, w - 1)
        tr = r - r0
        tc = c - c0
        # a NaN neighbour of weight 0 does not count
        top = dem[r0, c0] if tc == 0.0 else dem[r0, c0] * (1 - tc) + dem[r0, c1] * tc
        if tr == 0.0:
            out[p] = top
            continue
        bottom = dem[r1, c0] if tc == 0.0 else dem[r1, c0] * (1 - tc) + dem[r1, c1] * tc
        out[p] = top * (1 - tr) + bottom * tr


def bilinear_heights(dem: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """NaN-propagating bilinear interpolation of a DEM at fractional array positions.

    Parameters
    ----------
    dem : (H, W) float, NaN = nodata
    row, col : S float, array coordinates (pixel [r, c]'s centre at (r, c)); positions
        more than half a pixel outside the array give NaN.

    Returns
    -------
    S float64
    """
    row = np.asarray(row, dtype=np.float64)
    col = np.broadcast_to(np.asarray(col, dtype=np.float64), row.shape)
    out = np.empty(row.size)
    _bilinear(np.ascontiguousarray(dem, dtype=np.float64), np.ascontiguousarray(row).ravel(),
              np.ascontiguousarray(col).ravel(), out)
    return out.reshape(row.shape)
