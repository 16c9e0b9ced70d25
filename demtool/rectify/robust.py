"""The robust row-residual test both pointing fits share (:mod:`demtool.rectify.calibrated`,
:mod:`demtool.rectify.relative_pose`): matches within max(floor, k NMAD) of the median."""

from __future__ import annotations

import numpy as np

#: half-width of the inlier band in NMADs (1.4826 × the median absolute deviation)
ROBUST_NMADS = 4.0


def robust_inliers(residuals: np.ndarray, floor_px: float, *, skip_nan: bool,
                   nmads: float = ROBUST_NMADS) -> np.ndarray:
    """Matches whose residual lies within ``max(floor_px, nmads × NMAD)`` of the median.

    Parameters
    ----------
    residuals : (N,) float, pixels
        Row residuals of the matches.
    floor_px : float
        Least half-width of the band, pixels.
    skip_nan : bool
        True: NaN residuals are outliers and the median and NMAD are of the finite ones
        (the relative-pose fit, whose trial rotations may put a match behind a camera).
        False: a NaN residual makes the median NaN and no match an inlier (the pointing
        correction's residuals are finite by construction; a NaN there is a failure to
        see, not a match to drop).
    nmads : float
        Half-width of the band in NMADs.

    Returns
    -------
    (N,) bool
        True = inlier.
    """
    residuals = np.asarray(residuals, dtype=np.float64)
    finite = np.isfinite(residuals) if skip_nan else np.ones(residuals.shape, dtype=bool)
    med = np.median(residuals[finite])
    mad = 1.4826 * np.median(np.abs(residuals[finite] - med))
    with np.errstate(invalid="ignore"):
        return finite & (np.abs(residuals - med) <= max(floor_px, nmads * mad))
