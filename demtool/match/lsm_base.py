"""What the two template solvers share: status codes, the parameter count, numba flags
and the Cholesky solve of the normal equations.

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
