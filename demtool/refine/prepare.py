"""Preparing the inputs of shape from shading: the coarse DEM's gaps and spikes, and the
image resampled onto the DEM grid."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from demtool.errors import ProcessingError
from demtool.imaging.robust import NMAD_FACTOR
from demtool.logs import get_logger
from demtool.refine.filters import gaussian_lowpass, median_filter
from demtool.refine.params import RefineParams

log = get_logger(__name__)


class PreparedDem(NamedTuple):
    """The coarse DEM ready for :func:`demtool.refine.refine_heights`.

    Attributes
    ----------
    dem : (H, W) float32
        Heights, metres, finite: gaps filled and spikes replaced by the local median
        (the anchor of the low-passed heights and slopes).
    initial : (H, W) float32
        ``dem`` smoothed by a Gaussian of ``start_sigma`` pixels: where the iterations
        start.
    filled : (H, W) bool
        Pixels that were NaN and were filled.
    spikes : (H, W) bool
        Pixels replaced by the local median as spikes.
    nan_fraction : float
        Fraction of the grid that was NaN.
    """

    dem: np.ndarray
    initial: np.ndarray
    filled: np.ndarray
    spikes: np.ndarray
    nan_fraction: float




def despike(dem: np.ndarray, median: np.ndarray, threshold: float, size: int) -> np.ndarray:
    """Pixels that stand out of their local median by more than ``threshold`` spreads.

    A Hampel identifier (Hampel 1974; Pearson et al. 2016, *Generalized Hampel
    filters*, EURASIP J. Adv. Signal Process. 2016:87): with ``d = z − m`` the deviation
    from the moving median ``m`` and ``c`` the grid's median of ``d``, a pixel is a
    spike where ``|d − c|`` exceeds ``threshold`` × the normalised median absolute
    deviation (1.4826 MAD, the standard deviation of Gaussian scatter) of ``d`` in the
    same ``size`` × ``size`` window — or of the whole grid, where that is larger.  The
    local spread keeps real relief narrower than the window (a crater the median
    flattens deviates together with its neighbours) from counting as spikes, while an
    isolated blunder stands out of its window's spread.

    Parameters
    ----------
    dem, median : (H, W) float
        Heights and their moving median, metres, finite.
    threshold : float
        In robust standard deviations.
    size : int
        Odd window of the median, pixels.

    Returns
    -------
    (H, W) bool
    """
    deviation = np.asarray(dem, dtype=np.float32) - np.asarray(median, dtype=np.float32)
    spread = np.abs(deviation - np.float32(np.median(deviation)))
    global_spread = NMAD_FACTOR * float(np.median(spread))
    local_spread = np.float32(NMAD_FACTOR) * median_filter(spread, size)
    return spread > threshold * np.maximum(local_spread, np.float32(global_spread))


def prepare_dem(dem: np.ndarray, *, median_size: int = RefineParams.median,
                spike_threshold: float = RefineParams.spike_threshold,
                start_sigma: float = RefineParams.start_sigma,
                max_nan_fraction: float = RefineParams.max_nan_fraction) -> PreparedDem:
    """Fill the gaps of a coarse DEM, then remove its spikes with a median filter.

    Gaps are filled with :func:`demtool.imaging.interpolate.inpaint_springs` (the spring
    metaphor of the NavCam study); shape from shading then refines them from the
    shading like any other pixel.  The median filter (15 px in the NavCam study)
    removes the isolated matching blunders that would otherwise anchor the low-passed
    heights.  Applied to every pixel it also flattens real relief narrower than the
    window (crater floors and rims) — a bias that Edepth would then hold in the result
    (on the default synthetic scene the 21-px low-pass of a 15-px median is 0.030 m RMS
    from the truth's, of the input itself 0.020 m).  So the anchor (``dem``) takes the
    median only at spikes (:func:`despike`, ``spike_threshold`` robust standard
    deviations; 0 = everywhere, the study's use).

    The iterations start from the anchor smoothed by a Gaussian of ``start_sigma``
    pixels (``initial``; half power at the wavelength σ/0.187, 11 px for σ = 2,
    about the effective resolution of a stereo DEM matched with windows of 7–15 px):
    the relief a single image cannot see (slopes across the sun) keeps the coarse
    DEM's shape rather than its pixel-scale noise.  Measured on the default scene
    (slope-error ratio, noisy σ6 input / SIAM DEM): 0.488 / 0.486 from σ = 2,
    0.493 / 0.512 from the 15 px median, 0.577 / 0.535 from the anchor itself.
    σ = 1 instead of 2 (issue 12, slope ratio): demo line-scan 0.508 → 0.500, but demo
    image-frame 0.422 → 0.431, seed 1 line-scan 0.397 → 0.403, seed 1 image-frame
    0.322 → 0.335, 192-cell line-scan 0.612 → 0.621 — not adopted.

    Parameters
    ----------
    dem : (H, W) float
        Heights, metres; NaN = no data.
    median_size : int
        Odd window of the median filter in pixels; 0 or 1 disables it (then
        ``dem`` and ``initial`` are the filled input).
    spike_threshold : float
        Spike threshold of the anchor in robust standard deviations (NMAD) of the
        deviation from the median; 0 replaces every pixel by the median.
    start_sigma : float
        σ of the Gaussian (pixels, reflect borders) that smooths the anchor into the
        start surface; 0 starts from the anchor itself.
    max_nan_fraction : float
        Refuse a DEM with a larger fraction of NaN pixels.

    Returns
    -------
    PreparedDem

    Raises
    ------
    ProcessingError
        No finite height, or more gaps than ``max_nan_fraction``.
    """
    values = np.asarray(dem, dtype=np.float32)
    missing = ~np.isfinite(values)
    fraction = float(missing.mean())
    if missing.all():
        raise ProcessingError("the DEM has no finite height")
    if fraction > max_nan_fraction:
        raise ProcessingError(
            f"{100 * fraction:.1f}% of the DEM is NaN, more than the allowed "
            f"{100 * max_nan_fraction:.1f}% (--max-nan-fraction); fill or crop the DEM first")
    if missing.any():
        from demtool.imaging.interpolate import inpaint_springs

        values = np.asarray(inpaint_springs(values), dtype=np.float32)
        if not np.all(np.isfinite(values)):
            raise ProcessingError("filling the DEM's gaps left non-finite heights")
        log.info("filled %.2f%% of the DEM (%d pixels) by spring-metaphor inpainting",
                 100 * fraction, int(missing.sum()))
    spikes = np.zeros(values.shape, dtype=bool)
    if median_size > 1:
        median = median_filter(values, int(median_size))
        spikes = np.ones(values.shape, dtype=bool) if spike_threshold <= 0 else \
            despike(values, median, spike_threshold, int(median_size))
        values = np.where(spikes, median, values).astype(np.float32)
        log.info("median filter %d px: %d spikes (%.2f%%) replaced in the anchor DEM",
                 median_size, int(spikes.sum()), 100 * spikes.mean())
    initial = gaussian_lowpass(values, start_sigma) if start_sigma > 0 else values
    return PreparedDem(dem=values, initial=initial, filled=missing, spikes=spikes,
                       nan_fraction=fraction)
