"""Compiled (numba) kernel of :mod:`demtool.fuse.core`: Huber's IRLS, cell by cell.

The same arithmetic, in the same order, as the whole-array numpy form it replaces
(ten passes over ``(N, H, W)`` float64 stacks and their temporaries), so the weights are
the same to the bit (tests/fuse/test_core.py compares them with that form); one
parallel loop over rows instead, every step of a cell in registers.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(parallel=True, cache=True, nogil=True)
def huber_rows(values: np.ndarray, weights: np.ndarray, start: np.ndarray, scale: np.ndarray,
               c: float, iterations: int, out: np.ndarray) -> None:  # pragma: no cover
    """Huber weights of every cell into ``out`` (N, H, W).

    Per cell, from ``mu = start`` (0 where not finite), ``iterations`` times: ``u_i =
    |h_i − mu| / s``, ``w_i = prior_i min(1, c / max(u_i, 1e-12))`` for the present values
    (prior > 0; else 0), ``mu = Σ w_i h_i / Σ w_i`` where ``Σ w_i > 0`` (the sums in
    the stack's order).  ``values`` (N, H, W) metres (any value where the prior is 0),
    ``weights`` (N, H, W) the priors, ``start`` and ``scale`` (H, W), metres.
    """
    count, height, width = values.shape
    for r in nb.prange(height):
        for col in range(width):
            mu = start[r, col]
            if not np.isfinite(mu):
                mu = 0.0
            s = scale[r, col]
            for i in range(count):
                out[i, r, col] = weights[i, r, col]
            for _ in range(iterations):
                total = 0.0
                weighted = 0.0
                for i in range(count):
                    prior = weights[i, r, col]
                    if prior > 0:
                        h = values[i, r, col]
                        u = abs(h - mu) / s
                        w = prior * min(1.0, c / max(u, 1e-12))
                    else:
                        h = 0.0
                        w = 0.0
                    out[i, r, col] = w
                    total += w
                    weighted += w * h
                if total > 0:
                    mu = weighted / total
