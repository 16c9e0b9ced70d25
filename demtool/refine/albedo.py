"""Local albedo for shape from shading (Grumpe et al. 2015, as used by the NavCam study).

The albedo absorbs what the DEM's shading cannot explain at large scales: the image's
calibration (DN per unit reflectance), slow albedo variations and photometric model
errors.  At scales below the filter width the remaining intensity variations are
attributed to topography, which is what shape from shading recovers.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from demtool.refine.filters import masked_gaussian_lowpass
from demtool.tiling.rows import on_row_parts


def estimate_albedo(image: np.ndarray, modelled: np.ndarray, *, sigma: float,
                    weight: np.ndarray | None = None) -> np.ndarray:
    """Local albedo ``ρ = f_σ(I) / f_σ(R)``, the ratio of the low-passed image to the
    low-passed modelled unit-albedo reflectance of the current DEM.

    Grumpe et al. (2015): the albedo map is the ratio of the Gaussian-filtered
    observed intensities to the Gaussian-filtered intensities modelled from the
    current DEM, re-estimated as the DEM changes; σ_ρ = 21 px in the NavCam and
    LRO NAC studies.  Filtering numerator and
    denominator separately (rather than the pixelwise ratio) keeps dark, steep pixels
    from dominating.  Shadows and nodata are excluded through ``weight``
    (normalised convolution).  Within about σ_ρ of the grid border the mirrored
    boundary biases the estimate where the albedo has a gradient (a few percent for a
    ±25 % field varying over 300 px); the border taper of the intensity term keeps
    that bias from reaching the heights at the outermost pixels.

    Parameters
    ----------
    image : (H, W) float
        Observed intensities (any linear unit: DN, I/F); NaN = no data.
    modelled : (H, W) float
        Reflectance of the current DEM with unit albedo (same grid).
    sigma : float
        σ_ρ of the Gaussian low-pass, pixels.
    weight : (H, W) bool or float, optional
        Where the pixels count (default: finite image and modelled reflectance > 0).

    Returns
    -------
    albedo : (H, W) float32
        In the image's unit per unit reflectance (for an image in DN: DN; for I/F: the
        normal albedo), positive everywhere.

    Raises
    ------
    ValueError
        No pixel with a positive weight.
    """
    image = np.ascontiguousarray(image, dtype=np.float32)
    modelled = np.ascontiguousarray(modelled, dtype=np.float32)
    w = np.empty(image.shape, dtype=np.float32)
    if weight is None:
        _usable_weight(image, modelled, np.ones((1, 1), np.float32), False, w)
    else:
        _usable_weight(image, modelled, np.ascontiguousarray(weight), True, w)
    if not (w > 0).any():
        raise ValueError("estimate_albedo: no lit, valid pixel to estimate the albedo from")
    smooth_image = masked_gaussian_lowpass(image, w, sigma)
    smooth_model = masked_gaussian_lowpass(modelled, w, sigma)
    floor = np.float32(1e-6 * max(float(np.max(smooth_model)), 1e-12))
    albedo = np.empty(image.shape, dtype=np.float32)
    if not _ratio_is_bad(smooth_image, smooth_model, floor, albedo):
        return albedo
    bad = ~(albedo > 0)
    positive = albedo[~bad]
    fallback = np.float32(np.median(positive)) if positive.size else np.float32(1.0)
    return np.where(bad, fallback, albedo).astype(np.float32)


def _usable_weight(image: np.ndarray, modelled: np.ndarray, weight: np.ndarray,
                   weighted: bool, out: np.ndarray) -> None:
    """``out`` = the weight (1 when not ``weighted``) where the image and the model are
    finite and the model positive, else 0 (float32, rows on every core:
    :func:`demtool.tiling.rows.on_row_parts`)."""
    on_row_parts(lambda start, stop: _usable_weight_rows(image, modelled, weight, weighted,
                                                         out, start, stop), image.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _usable_weight_rows(image, modelled, weight, weighted, out, start,
                        stop):  # pragma: no cover - compiled
    width = image.shape[1]
    for r in range(start, stop):
        for c in range(width):
            m = modelled[r, c]
            usable = np.isfinite(image[r, c]) and np.isfinite(m) and m > 0
            w = np.float32(weight[r, c]) if weighted else np.float32(1.0)
            out[r, c] = w if usable else np.float32(0.0)


def _ratio_is_bad(smooth_image: np.ndarray, smooth_model: np.ndarray, floor: np.float32,
                  out: np.ndarray) -> bool:
    """``out = smooth_image / max(smooth_model, floor)`` (NaN kept, as ``np.maximum``);
    True when some ratio is not positive."""
    bad = np.zeros(out.shape[0], dtype=np.bool_)
    on_row_parts(lambda start, stop: _ratio_rows(smooth_image, smooth_model, floor, out, bad,
                                                 start, stop), out.shape[0])
    return bool(bad.any())


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _ratio_rows(smooth_image, smooth_model, floor, out, bad, start,
                stop):  # pragma: no cover - compiled
    """Rows ``start … stop − 1`` of :func:`_ratio_is_bad`; ``bad[r]`` True when a ratio of
    row r is not positive."""
    width = out.shape[1]
    for r in range(start, stop):
        for c in range(width):
            m = smooth_model[r, c]
            ratio = smooth_image[r, c] / (m if not m < floor else floor)
            out[r, c] = ratio
            if not ratio > 0:
                bad[r] = True
