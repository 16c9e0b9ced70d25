"""Mutual information of a stereo pair's grey levels: the MI matching cost of SGM.

References
----------
Kim, J., Kolmogorov, V. & Zabih, R. (2003), Visual correspondence using energy
minimization and mutual information, ICCV, 1033–1040 (Taylor expansion of MI).
Hirschmüller, H. (2008), Stereo processing by semiglobal matching and mutual
information, IEEE TPAMI 30(2), 328–341, §3.1.2 (eqs. 5–12, MI matching cost).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Scale of the MI pixel cost: integer units per nat of pointwise mutual information,
# and the cap (in nats) of the cost of pairs never seen together.
MI_UNITS_PER_NAT = 8.0
MI_MAX_NATS = 8.0


@njit(nogil=True, cache=True)
def _joint_histogram(left_levels, right_levels, left_valid, right_valid, disparity, levels):
    height, width = left_levels.shape
    histogram = np.zeros((levels, levels), dtype=np.float64)
    for y in range(height):
        for x in range(width):
            d = disparity[y, x]
            if not left_valid[y, x] or not np.isfinite(d):
                continue
            xr = x - int(np.rint(d))
            if xr < 0 or xr >= width or not right_valid[y, xr]:
                continue
            histogram[left_levels[y, x], right_levels[y, xr]] += 1.0
    return histogram


def mutual_information_table(left_levels: np.ndarray, right_levels: np.ndarray,
                             left_valid: np.ndarray, right_valid: np.ndarray,
                             disparity: np.ndarray, *, levels: int,
                             sigma: float = 1.0) -> tuple[np.ndarray, int]:
    """Pointwise mutual information of every grey-level pair, under a disparity estimate.

    The joint histogram of corresponding pixels (left pixel p, right pixel p − d(p))
    gives P_{I1,I2}; marginals are taken from it, so occluded pixels do not enter
    (Hirschmüller 2008, §3.1.2).  Entropies are expanded per pixel pair
    (Kim et al. 2003) with Parzen (Gaussian) smoothing before and after the log:

        h_{I1,I2}(i, k) = −log(P_{I1,I2} ⊗ g)(i, k) ⊗ g                   (eq. 12)
        h_{I}(i)        = −log(P_{I} ⊗ g)(i) ⊗ g                           (eq. 13)
        mi(i, k)        = h_{I1}(i) + h_{I2}(k) − h_{I1,I2}(i, k)          (eq. 14)

    The 1/n factor of eq. 12 is left out: it scales every cost alike, which the
    integer scaling of :func:`mi_cost_table` absorbs.

    Parameters
    ----------
    left_levels, right_levels : (H, W) uint8, grey levels 0 .. levels − 1
    left_valid, right_valid : (H, W) bool
    disparity : (H, W) float, pixels, NaN = unknown (excluded from the histogram)
    levels : int
    sigma : float
        Standard deviation of the Parzen window, in grey levels.

    Returns
    -------
    mi : (levels, levels) float64, nats (higher = more likely a correct match)
    count : int, number of pixel pairs in the histogram
    """
    histogram = _joint_histogram(left_levels, right_levels, left_valid, right_valid,
                                 np.asarray(disparity, dtype=np.float32), levels)
    count = int(histogram.sum())
    if count == 0:
        return np.zeros((levels, levels)), 0
    joint = histogram / count
    tiny = 1e-12
    inside = gaussian_matrix(levels, sigma, "constant")  # Parzen window, zero outside
    edge = gaussian_matrix(levels, sigma, "nearest")  # smoothing of −log P, edges extended
    h_joint = edge @ -np.log(np.maximum(inside @ joint @ inside.T, tiny)) @ edge.T
    h_left = edge @ -np.log(np.maximum(inside @ joint.sum(1), tiny))
    h_right = edge @ -np.log(np.maximum(inside @ joint.sum(0), tiny))
    return h_left[:, None] + h_right[None, :] - h_joint, count


def gaussian_matrix(size: int, sigma: float, mode: str, truncate: float = 4.0) -> np.ndarray:
    """Matrix G of a 1-D Gaussian filter: ``G @ v`` smooths a vector of ``size`` samples.

    The kernel is ``scipy.ndimage.gaussian_filter1d``'s (normalised, radius
    ``int(truncate·σ + 0.5)``); ``mode`` "constant" treats samples outside as 0,
    "nearest" repeats the edge samples.  A 2-D array A is smoothed along both axes by
    ``G @ A @ G.T`` — cheap for the small (levels × levels) MI histograms, and it
    spares the import of scipy.ndimage.

    Returns
    -------
    (size, size) float64
    """
    radius = int(truncate * sigma + 0.5)
    offsets = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 * (offsets / sigma) ** 2)
    weights /= weights.sum()
    matrix = np.zeros((size, size))
    rows = np.arange(size)
    for offset, weight in zip(offsets, weights, strict=True):
        columns = rows + offset
        if mode == "constant":
            inside = (columns >= 0) & (columns < size)
            matrix[rows[inside], columns[inside]] += weight
        elif mode == "nearest":
            np.add.at(matrix, (rows, np.clip(columns, 0, size - 1)), weight)
        else:
            raise ValueError(f"unknown mode {mode!r}: should be 'constant' or 'nearest'")
    return matrix


def mi_cost_table(mi: np.ndarray) -> np.ndarray:
    """Integer pixel cost of every grey-level pair from pointwise MI (cost = −mi, shifted).

    ``cost = round(MI_UNITS_PER_NAT · min(max(mi) − mi, MI_MAX_NATS))``: the best
    pair costs 0 and pairs never seen together cost ``MI_UNITS_PER_NAT · MI_MAX_NATS``.

    Returns
    -------
    (levels, levels) uint16
    """
    cost = np.minimum(mi.max() - mi, MI_MAX_NATS) * MI_UNITS_PER_NAT
    return np.rint(cost).astype(np.uint16)
