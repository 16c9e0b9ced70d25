"""What the two template solvers share: status codes, the parameter count, numba flags,
the Cholesky solve of the normal equations, and the steps both kernels take alike
(opening a template, the cubic cell of a warped point, the divergence test, storing a
solution).

Used by Grün's forward-additive LSM (:mod:`demtool.match.lsm`) and the
inverse-compositional Gauss–Newton form (:mod:`demtool.match.icgn`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Number of LSM parameters: 6 affine + 2 radiometric.
N_PARAMS = 8

# Status codes of one LSM solution (``LSMResult.status``).
CONVERGED = 0
NOT_CONVERGED = 1  # hit the iteration limit
LEFT_INVALID = 2  # the template touches nodata or the image border
RIGHT_INVALID = 3  # the resampled window left the image or touched nodata
SINGULAR = 4  # normal equations not positive definite (no texture)
DIVERGED = 5  # the shift or the affine terms ran away

# IEEE-safe fast-math flags (no 'nnan'/'ninf': NaN marks failures here)
_FASTMATH = {"contract", "reassoc", "arcp", "nsz"}


@njit(cache=True, inline="always")
def _cholesky_solve(normal: np.ndarray, rhs: np.ndarray, out: np.ndarray,
                    lower: np.ndarray) -> bool:
    """Solve ``normal @ out = rhs`` (symmetric positive definite); False if not SPD."""
    n = normal.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = normal[i, j]
            for k in range(j):
                s -= lower[i, k] * lower[j, k]
            if i == j:
                if s <= 1e-12 * max(1.0, abs(normal[i, i])):
                    return False
                lower[i, i] = np.sqrt(s)
            else:
                lower[i, j] = s / lower[j, j]
    for i in range(n):  # forward substitution
        s = rhs[i]
        for k in range(i):
            s -= lower[i, k] * out[k]
        out[i] = s / lower[i, i]
    for i in range(n - 1, -1, -1):  # back substitution
        s = out[i]
        for k in range(i + 1, n):
            s -= lower[k, i] * out[k]
        out[i] = s / lower[i, i]
    return True


@njit(cache=True, inline="always")
def _open_template(result: np.ndarray, left_ok: np.ndarray, row: int, col: int,
                   half: int) -> bool:
    """Clear ``result`` (x, y, correlation, sigma_x NaN; 0 iterations) and check that the
    template of half size ``half`` centred on left pixel (row, col) lies in the image.

    Returns False, with status ``LEFT_INVALID`` in ``result[5]``, when it does not.  The
    caller checks ``left_ok`` over the template (IC-GN inside its first pass: a separate
    pass there lets the compiler reorder that pass's sums, changing the last bits).
    """
    result[0] = np.nan
    result[1] = np.nan
    result[2] = np.nan
    result[3] = np.nan
    result[4] = 0.0
    height, width = left_ok.shape
    if row - half < 0 or row + half >= height or col - half < 0 or col + half >= width:
        result[5] = LEFT_INVALID
        return False
    return True


@njit(cache=True, inline="always")
def _cubic_cell(right_ok4: np.ndarray, xs: float, ys: float) -> tuple[int, int, bool]:
    """Integer cell (xi, yi) of the right-image point (xs, ys), and whether cubic
    convolution there sees only data (``right_ok4``: :func:`lsm.cubic_support_mask`)."""
    xi = int(np.floor(xs))
    yi = int(np.floor(ys))
    height, width = right_ok4.shape
    inside = 1 <= xi < width - 2 and 1 <= yi < height - 2
    return xi, yi, inside and right_ok4[yi, xi]


@njit(cache=True, inline="always")
def _ran_away(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float,
              x0: float, y0: float, max_shift: float) -> bool:
    """The affine warp (x' = a0 + a1 u + a2 v, y' = b0 + b1 u + b2 v) has diverged: its
    centre moved more than ``max_shift`` px from the start (x0, y0), or its shape more
    than 0.5 from the identity."""
    return (abs(a0 - x0) > max_shift or abs(b0 - y0) > max_shift
            or abs(a1 - 1.0) > 0.5 or abs(b2 - 1.0) > 0.5
            or abs(a2) > 0.5 or abs(b1) > 0.5)


@njit(cache=True, inline="always")
def _store_solution(result: np.ndarray, x: float, y: float, corr: float, sigma_x: float,
                    iterations: int) -> None:
    """Write a converged solution into ``result[:6]``."""
    result[0] = x
    result[1] = y
    result[2] = corr
    result[3] = sigma_x
    result[4] = iterations
    result[5] = CONVERGED
