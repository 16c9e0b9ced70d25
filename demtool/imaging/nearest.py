"""Nearest neighbours both ways from a block of a squared-distance matrix (compiled).

:func:`demtool.imaging.features.match_descriptors` computes the squared distances of
descriptor sets with one BLAS product per block of rows; this pass reads a block once,
in memory order, for each row's two nearest columns and each column's nearest row.
numpy needed an ``argpartition`` along the rows and an ``argmin`` down the columns,
which copies the block transposed first: 0.33 CPU s against 0.14 for 4000 × 4000
descriptors, 1.22 against 0.58 for 8000 × 8000 (the BLAS product is the rest).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def nearest_both_ways(d2: np.ndarray, first_row: int, indices: np.ndarray,
                      distances: np.ndarray, best_a_for_b: np.ndarray,
                      best_b_distance: np.ndarray) -> None:  # pragma: no cover - compiled
    """Fold the rows ``first_row …`` of a squared-distance matrix into the running results.

    Parameters
    ----------
    d2 : (R, Nb) float32
        Squared distances of rows ``first_row … first_row + R − 1`` of ``a`` to every row
        of ``b``; values below 0 (rounding of ‖a‖² + ‖b‖² − 2 a·b) count as 0.
    first_row : int
        Row of ``a`` of the block's first row.
    indices, distances : (Na, 2) int64, float64
        Written for the block's rows: the nearest and second-nearest column and their
        squared distances, nearest first (index −1, distance inf where ``b`` has one
        row).  Ties: the lower column first.
    best_a_for_b, best_b_distance : (Nb,) int64, float64
        Each column's nearest row of ``a`` so far and its squared distance, updated where
        a row of the block is strictly nearer (so the lowest such row wins, as
        ``argmin`` does over the whole matrix).
    """
    rows, columns = d2.shape
    for r in range(rows):
        best, second = np.inf, np.inf
        best_j, second_j = -1, -1
        row = first_row + r
        for j in range(columns):
            value = max(np.float64(d2[r, j]), 0.0)
            if value < best:
                second, second_j = best, best_j
                best, best_j = value, j
            elif value < second:
                second, second_j = value, j
            if value < best_b_distance[j]:
                best_b_distance[j] = value
                best_a_for_b[j] = row
        indices[row, 0], indices[row, 1] = best_j, second_j
        distances[row, 0], distances[row, 1] = best, second
