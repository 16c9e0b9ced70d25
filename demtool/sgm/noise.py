"""Noise of the guide image and the κ of SGM's adaptive P2 (split out of
:mod:`demtool.sgm.matcher`, which re-exports these names).

:func:`noise_sigma` estimates an image's pixel noise with Immerkær's operator (an O(n)
histogram median on the uint8 guide); :func:`p2_kappa` turns it into the intensity step
above which the adaptive P2 shrinks, so that noise steps are not taken for edges.

References
----------
Immerkær, J. (1996), Fast noise variance estimation, CVIU 64(2), 300–302.
Hirschmüller, H. (2008), Stereo processing by semiglobal matching and mutual
information, IEEE TPAMI 30(2), 328–341 (the intensity-adaptive P2, sect. III-C).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from demtool.sgm.disparity import in_halves

P2_KAPPA = 8  # grey levels (of 256) above which the adaptive P2 shrinks, at least
P2_KAPPA_NOISE = 3.0  # ... and at least this many times the guide image's noise σ


@njit(cache=True, nogil=True)
def _laplacian_histogram(image: np.ndarray, valid: np.ndarray, counts: np.ndarray,
                         start: int, stop: int) -> int:
    """Histogram of |Immerkær response| of a uint8 image where the 3 × 3 window is valid,
    over the rows ``max(start, 1) … min(stop, H − 1) − 1``.

    ``counts`` has 4 · 255 · 4 + 1 bins (the largest response); returns the count.
    """
    height, width = image.shape
    total = 0
    for y in range(max(start, 1), min(stop, height - 1)):
        for x in range(1, width - 1):
            if not (valid[y - 1, x - 1] and valid[y - 1, x + 1] and valid[y + 1, x - 1]
                    and valid[y + 1, x + 1] and valid[y, x]):
                continue
            r = np.int32(0)  # invalid pixels count as 0, as in the float path
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    if valid[y + dy, x + dx]:
                        weight = (2 - abs(dy)) * (2 - abs(dx)) * (1 if (dx + dy) % 2 == 0
                                                                  else -1)
                        r += weight * np.int32(image[y + dy, x + dx])
            counts[abs(r)] += 1
            total += 1
    return total


def _histogram_median(counts: np.ndarray, total: int) -> float:
    """Median of ``total`` integer samples given by their histogram (numpy's rule)."""
    cumulative = np.cumsum(counts)
    low = int(np.searchsorted(cumulative, (total - 1) // 2 + 1))
    high = int(np.searchsorted(cumulative, total // 2 + 1))
    return 0.5 * (low + high)


def noise_sigma(image: np.ndarray, valid: np.ndarray) -> float:
    """Robust standard deviation of an image's pixel noise, in its own units.

    Immerkær's (1996) operator N = [[1, −2, 1], [−2, 4, −2], [1, −2, 1]] cancels
    locally planar signal; its response to white noise of σ has standard deviation
    6σ.  The median absolute response (× 1.4826, over windows of valid pixels) is
    used instead of the paper's mean so that edges and texture weigh little.

    Parameters
    ----------
    image : (H, W) float
    valid : (H, W) bool

    Returns
    -------
    float
        σ (0 for images under 3 × 3 pixels).

    References
    ----------
    Immerkær, J. (1996), Fast noise variance estimation, CVIU 64(2), 300–302.
    """
    if min(image.shape) < 3:
        return 0.0
    if image.dtype == np.uint8:  # the guide: integer responses, an O(n) histogram median
        mask = np.ascontiguousarray(valid, dtype=np.bool_)
        counts = np.zeros((2, 4 * 255 * 4 + 1), dtype=np.int64)  # one per half of the rows
        totals = [0, 0]

        def half(start: int, stop: int) -> None:
            totals[int(start > 0)] = _laplacian_histogram(image, mask, counts[int(start > 0)],
                                                     start, stop)

        in_halves(half, image.shape[0])
        counts, total = counts.sum(axis=0), sum(totals)  # integer counts: exact
        return 0.0 if total == 0 else float(1.4826 * _histogram_median(counts, total) / 6.0)
    a = np.where(valid, image, 0.0).astype(np.float64)
    response = (a[:-2, :-2] - 2 * a[:-2, 1:-1] + a[:-2, 2:]
                - 2 * a[1:-1, :-2] + 4 * a[1:-1, 1:-1] - 2 * a[1:-1, 2:]
                + a[2:, :-2] - 2 * a[2:, 1:-1] + a[2:, 2:])
    ok = valid[:-2, :-2] & valid[:-2, 2:] & valid[2:, :-2] & valid[2:, 2:] & valid[1:-1, 1:-1]
    if not ok.any():
        return 0.0
    return float(1.4826 * np.median(np.abs(response[ok])) / 6.0)


def p2_kappa(guide: np.ndarray, valid: np.ndarray) -> int:
    """κ of the adaptive P2: ``max(P2_KAPPA, P2_KAPPA_NOISE · σ)`` grey levels of the guide.

    Intensity steps within a few noise σ are not edges: on a noisy weak-texture image
    a fixed κ would lower P2 almost everywhere and leave SGM without smoothness.
    """
    return int(max(P2_KAPPA, round(P2_KAPPA_NOISE * noise_sigma(guide, valid))))
