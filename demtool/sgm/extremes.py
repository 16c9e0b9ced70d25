"""Maximum and minimum over square windows, for the depth-edge zones of cost "auto".

:func:`box_max` equals ``scipy.ndimage.maximum_filter(values, size=2·radius + 1)`` (its
default ``mode="reflect"``: a window reaching past the border sees only pixels it
already holds, so the result is the extreme over the window clipped to the image)
for arrays without NaN, and :func:`box_min` the ``minimum_filter``.  Both are
separable and exact; each axis runs van Herk's and Gil & Werman's algorithm (three
comparisons per pixel whatever the window), the pass along the columns over whole
rows at a time, so it vectorises.  On a 2048² float32 image with a 25 × 25 window
that is several times faster than scipy's filters, which took about 1 s of the
default cost's CPU at that size.

References
----------
van Herk, M. (1992), A fast algorithm for local minimum and maximum filters on
rectangular and octagonal kernels, Pattern Recognition Letters 13(7), 517–521.
Gil, J. & Werman, M. (1993), Computing 2-D min, median, and max filters, IEEE TPAMI
15(5), 504–507.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _max_along_columns(values, radius, out):
    """out[y, x] = max of values[y − r … y + r, x] (rows clipped to the image)."""
    height, width = values.shape
    size = 2 * radius + 1
    n = height + 2 * radius  # the rows padded with −inf at both ends
    prefix = np.empty((n, width), dtype=values.dtype)
    suffix = np.empty((n, width), dtype=values.dtype)
    low = -np.inf
    for j in range(n):
        y = j - radius
        first = j % size == 0
        for x in range(width):
            v = values[y, x] if 0 <= y < height else low
            prefix[j, x] = v if first else max(prefix[j - 1, x], v)
    for j in range(n - 1, -1, -1):
        y = j - radius
        last = j % size == size - 1 or j == n - 1
        for x in range(width):
            v = values[y, x] if 0 <= y < height else low
            suffix[j, x] = v if last else max(suffix[j + 1, x], v)
    for y in range(height):
        for x in range(width):
            out[y, x] = max(suffix[y, x], prefix[y + 2 * radius, x])


@njit(cache=True, nogil=True)
def _max_along_rows(values, radius, out):
    """out[y, x] = max of values[y, x − r … x + r] (columns clipped to the image)."""
    height, width = values.shape
    size = 2 * radius + 1
    n = width + 2 * radius
    prefix = np.empty(n, dtype=values.dtype)
    suffix = np.empty(n, dtype=values.dtype)
    low = -np.inf
    for y in range(height):
        for j in range(n):
            x = j - radius
            v = values[y, x] if 0 <= x < width else low
            prefix[j] = v if j % size == 0 else max(prefix[j - 1], v)
        for j in range(n - 1, -1, -1):
            x = j - radius
            v = values[y, x] if 0 <= x < width else low
            suffix[j] = v if (j % size == size - 1 or j == n - 1) else max(suffix[j + 1], v)
        for x in range(width):
            out[y, x] = max(suffix[x], prefix[x + 2 * radius])


def box_max(values: np.ndarray, radius: int) -> np.ndarray:
    """(H, W): the maximum over the (2·radius + 1)² window around each pixel, clipped
    to the image (``values`` without NaN, ±inf allowed; float64 stays float64, any
    other type becomes float32)."""
    values = np.ascontiguousarray(values)
    if values.dtype != np.float64:
        values = values.astype(np.float32, copy=False)
    columns = np.empty_like(values)
    _max_along_columns(values, int(radius), columns)
    out = np.empty_like(values)
    _max_along_rows(columns, int(radius), out)
    return out


def box_min(values: np.ndarray, radius: int) -> np.ndarray:
    """(H, W): the minimum over the (2·radius + 1)² window (−max of −values: exact)."""
    values = np.asarray(values)
    return -box_max(-(values if values.dtype == np.float64 else
                      values.astype(np.float32, copy=False)), radius)
