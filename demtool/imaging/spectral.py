"""Spectral coherence between two DEMs: how much of a DEM's detail is real.

The *effective resolution* of a DEM is the finest scale at which it still agrees with
a reference.  We measure it with the radially averaged magnitude-squared coherence of
the two surfaces (Bendat & Piersol, *Random Data*, 4th ed., 2010, eq. 5.90, with the
ensemble average replaced by an average over annuli of the 2-D spectrum):

.. math::

    \\gamma^2(f) = \\frac{|\\langle S_{ab}\\rangle_f|^2}
                        {\\langle S_{aa}\\rangle_f \\, \\langle S_{bb}\\rangle_f},

where :math:`S_{ab} = A B^*` is the cross spectrum of the detrended, tapered DEMs,
:math:`S_{aa} = |A|^2`, :math:`S_{bb} = |B|^2`, and :math:`\\langle\\cdot\\rangle_f`
averages over the annulus of radial frequency ``f``.  If ``b = h * a + n`` with a
filter of real gain ``H(f)`` and independent noise ``n``, then
:math:`\\gamma^2 = H^2 P_a / (H^2 P_a + P_n)`: the coherence is 1 where the DEM
reproduces the reference and falls to the noise floor where its detail is smoothed
away or invented.  The frequency where it drops below 0.5 (signal power equals noise
power) is the coherent cut-off; its inverse is the effective resolution (wavelength).

Because the annulus average of a real field's spectrum pairs each frequency with its
conjugate, :math:`\\langle S_{ab}\\rangle_f` is real: a residual horizontal shift
between the DEMs (a phase ramp) lowers the coherence, as it should for a comparison
made in place.  Co-register before measuring.

NaN handling (``nan_policy``): ``"crop"`` uses the largest axis-aligned rectangle in
which both DEMs are valid; ``"fill"`` uses the whole common extent with the invalid
pixels set to the fitted plane (zero after detrending) — both DEMs get the same mask,
so identical inputs still give coherence 1, but large holes smear the spectrum.
``"auto"`` (default) crops when the largest valid rectangle holds at least half of the
common valid pixels and is at least 32 × 32 pixels, and fills otherwise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from demtool.errors import ProcessingError

__all__ = [
    "CoherenceSpectrum",
    "coherence_cutoff",
    "coherence_spectrum",
    "cutoff_from_curve",
    "largest_valid_rectangle",
    "periodic_hann",
    "periodic_tukey",
    "radial_coherence",
]

MIN_SIZE = 16  # smallest side (pixels) on which a spectrum is computed


class CoherenceSpectrum(NamedTuple):
    """Radially averaged spectra of a DEM and its reference.

    Attributes
    ----------
    frequency : (K,) float64
        Mean radial frequency of each annulus, cycles per metre (per unit of ``spacing``).
    coherence : (K,) float64
        Magnitude-squared coherence, in [0, 1].
    power_dem, power_reference : (K,) float64
        Annulus-averaged power spectral density of each (detrended, tapered) DEM, m² m².
    count : (K,) int64
        Number of spectral samples in each annulus.
    window : tuple of 4 int
        ``(row0, col0, row1, col1)`` of the part of the arrays that was analysed
        (half-open), after NaN cropping.
    """

    frequency: np.ndarray
    coherence: np.ndarray
    power_dem: np.ndarray
    power_reference: np.ndarray
    count: np.ndarray
    window: tuple[int, int, int, int]


@njit(cache=True)
def _largest_rectangle(valid: np.ndarray) -> tuple[int, int, int, int]:
    # Maximal rectangle of True in a binary matrix: histogram of run heights per row,
    # then the largest rectangle under each row's histogram with a monotone stack.
    rows, cols = valid.shape
    heights = np.zeros(cols + 1, dtype=np.int64)
    stack = np.empty(cols + 2, dtype=np.int64)
    best_area = 0
    best = (0, 0, 0, 0)
    for r in range(rows):
        for c in range(cols):
            heights[c] = heights[c] + 1 if valid[r, c] else 0
        top = 0
        for c in range(cols + 1):
            h = heights[c] if c < cols else 0
            while top > 0 and heights[stack[top - 1]] >= h:
                top -= 1
                height = heights[stack[top]]
                left = stack[top - 1] + 1 if top > 0 else 0
                area = height * (c - left)
                if area > best_area:
                    best_area = area
                    best = (r - height + 1, left, r + 1, c)
            stack[top] = c
            top += 1
    return best


def largest_valid_rectangle(valid: np.ndarray) -> tuple[int, int, int, int]:
    """Largest axis-aligned rectangle of True pixels.

    Parameters
    ----------
    valid : (H, W) bool
        True where data are valid.

    Returns
    -------
    tuple of 4 int
        ``(row0, col0, row1, col1)``, half-open; all zeros when nothing is valid.
    """
    return _largest_rectangle(np.ascontiguousarray(valid, dtype=np.bool_))


def periodic_hann(length: int) -> np.ndarray:
    """The periodic Hann window of ``length`` samples, float64.

    scipy.signal.windows.hann(length, sym=False) value for value (its general cosine
    window 0.5 − 0.5 cos over ``length + 1`` points, the last dropped), without importing
    scipy.signal: that import alone took 0.5 s of each ``compare``.
    """
    if length <= 1:
        return np.ones(length)
    angle = np.linspace(-np.pi, np.pi, length + 1)
    return (0.5 + 0.5 * np.cos(angle))[:-1]


def periodic_tukey(length: int, alpha: float) -> np.ndarray:
    """The periodic Tukey (tapered cosine) window, float64: a flat top and cosine tapers
    over ``alpha`` of the length; scipy.signal.windows.tukey(length, alpha, sym=False)
    value for value (the same formula over ``length + 1`` points, the last dropped)."""
    if length <= 1 or alpha <= 0:
        return np.ones(length)
    if alpha >= 1.0:
        return periodic_hann(length)
    m = length + 1
    n = np.arange(0, m, dtype=np.float64)
    width = int(math.floor(alpha * (m - 1) / 2.0))
    n1, n2, n3 = n[0:width + 1], n[width + 1:m - width - 1], n[m - width - 1:]
    w1 = 0.5 * (1 + np.cos(np.pi * (-1 + 2.0 * n1 / alpha / (m - 1))))
    w3 = 0.5 * (1 + np.cos(np.pi * (-2.0 / alpha + 1 + 2.0 * n3 / alpha / (m - 1))))
    return np.concatenate((w1, np.ones(n2.shape), w3))[:-1]


def _taper(shape: tuple[int, int], window: str, alpha: float) -> np.ndarray:
    if window == "none":
        return np.ones(shape)
    if window == "hann":
        rows, cols = periodic_hann(shape[0]), periodic_hann(shape[1])
    elif window == "tukey":
        rows, cols = periodic_tukey(shape[0], alpha), periodic_tukey(shape[1], alpha)
    else:
        raise ValueError(f"unknown window {window!r}: should be one of hann, tukey, none")
    return np.outer(rows, cols)


class _PlaneBasis(NamedTuple):
    """The valid pixels' coordinates, centred, and their normal matrix (one for both
    DEMs of a spectrum: they share the valid pixels)."""

    row_offsets: np.ndarray  # (n,) row − mean row of each valid pixel
    col_offsets: np.ndarray  # (n,) col − mean col
    mean_row: float
    mean_col: float
    normal: np.ndarray  # (3, 3) of the basis [1, row − mean row, col − mean col]


def _plane_basis(valid: np.ndarray) -> _PlaneBasis:
    rows, cols = np.nonzero(valid)
    mean_row, mean_col = float(rows.mean()), float(cols.mean())
    dr, dc = rows - mean_row, cols - mean_col
    sr, sc = float(dr.sum()), float(dc.sum())  # ~0: kept, the fit stays exact
    normal = np.array([[rows.size, sr, sc],
                       [sr, float(dr @ dr), float(dr @ dc)],
                       [sc, float(dr @ dc), float(dc @ dc)]])
    return _PlaneBasis(dr, dc, mean_row, mean_col, normal)


def _detrend(values: np.ndarray, valid: np.ndarray, basis: _PlaneBasis | None = None
             ) -> np.ndarray:
    """Subtract the least-squares plane of the valid pixels; invalid pixels become 0.

    The plane is solved from its normal equations in coordinates centred on the valid
    pixels (their normal matrix is then diagonal but for the rows' and columns'
    correlation, well conditioned at any size): the least-squares plane to float
    rounding, without the SVD of an (n, 3) design (3.5 CPU s of each 4096² spectrum).
    ``basis``: :func:`_plane_basis` of ``valid``, when the caller has it."""
    if basis is None:
        basis = _plane_basis(valid)
    z = values[valid].astype(np.float64)
    rhs = np.array([z.sum(), basis.row_offsets @ z, basis.col_offsets @ z])
    coef = np.linalg.lstsq(basis.normal, rhs, rcond=None)[0]  # 3 x 3: any rank
    rows = np.arange(values.shape[0])[:, None] - basis.mean_row
    cols = np.arange(values.shape[1])[None, :] - basis.mean_col
    plane = coef[0] + coef[1] * rows + coef[2] * cols
    return np.where(valid, values - plane, 0.0)


def _select_window(valid: np.ndarray, nan_policy: str) -> tuple[int, int, int, int]:
    full = (0, 0, valid.shape[0], valid.shape[1])
    if valid.all():
        return full
    if nan_policy == "fill":
        return full
    r0, c0, r1, c1 = largest_valid_rectangle(valid)
    large_enough = min(r1 - r0, c1 - c0) >= 32 and (r1 - r0) * (c1 - c0) >= 0.5 * valid.sum()
    if nan_policy == "crop" or large_enough:
        return r0, c0, r1, c1
    return full


def coherence_spectrum(dem: np.ndarray, reference: np.ndarray, *, spacing: float = 1.0,
                       window: str = "hann", tukey_alpha: float = 0.25,
                       nan_policy: str = "auto", bin_width: float | None = None,
                       threads: int = 1) -> CoherenceSpectrum:
    """Radially averaged coherence and power spectra of a DEM against a reference.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid
        Two DEMs on the same grid (co-registered).  Not modified.
    spacing : float
        Pixel spacing (metres, or any unit: frequencies come out per that unit).
    window : {"hann", "tukey", "none"}
        Taper applied (2-D outer product) after detrending, against edge leakage.
    tukey_alpha : float
        Taper fraction of the Tukey window.
    nan_policy : {"auto", "crop", "fill"}
        How NaN pixels are handled (see the module docstring).
    bin_width : float, optional
        Width of the frequency annuli (cycles per unit); default ``1 / (n * spacing)``
        with ``n`` the shorter side of the analysed window (one FFT bin).
    threads : int
        With 2 or more, the reference is detrended and transformed on a second thread
        while this one does the DEM (numpy's least squares and FFT release the GIL); the
        same operations on the same arrays, so the same numbers.

    Returns
    -------
    CoherenceSpectrum
        Annuli from the first non-zero frequency bin up to the Nyquist frequency of the
        shorter axis, ``0.5 / spacing``; empty annuli are dropped.

    Raises
    ------
    ValueError
        Shapes differ, bad spacing, window or policy.
    ProcessingError
        Fewer than 16 × 16 common valid pixels, or a DEM is constant.
    """
    a = np.asarray(dem, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"dem and reference must be 2-D arrays of one shape, got "
                         f"{a.shape} and {b.shape}")
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be positive, got {spacing}")
    if nan_policy not in ("auto", "crop", "fill"):
        raise ValueError(f"unknown nan_policy {nan_policy!r}: should be auto, crop or fill")
    valid = np.isfinite(a) & np.isfinite(b)
    r0, c0, r1, c1 = _select_window(valid, nan_policy)
    if min(r1 - r0, c1 - c0) < MIN_SIZE or valid.sum() < MIN_SIZE**2:
        raise ProcessingError(f"too few common valid pixels for a spectrum (need a "
                              f"{MIN_SIZE} x {MIN_SIZE} window; largest usable is "
                              f"{r1 - r0} x {c1 - c0})")
    valid = valid[r0:r1, c0:c1]
    taper = _taper(valid.shape, window, tukey_alpha)
    basis = _plane_basis(valid)  # one for both: they share the valid pixels

    def spectrum_of(values: np.ndarray) -> np.ndarray | None:
        """The FFT of the detrended, tapered values; None for a plane."""
        detrended = _detrend(values, valid, basis) * taper
        scale = np.ptp(values[valid]) if valid.any() else 0.0
        if not np.abs(detrended).max() > 1e-9 * max(scale, 1e-30):
            return None
        return np.fft.rfft2(detrended)

    if threads >= 2:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=1) as side:
            later = side.submit(spectrum_of, b[r0:r1, c0:c1])
            spec_a = spectrum_of(a[r0:r1, c0:c1])
            spec_b = later.result()
    else:
        spec_a = spectrum_of(a[r0:r1, c0:c1])
        spec_b = spectrum_of(b[r0:r1, c0:c1]) if spec_a is not None else None
    if spec_a is None or spec_b is None:
        raise ProcessingError("a DEM is a plane over the common valid area: its "
                              "coherence is undefined")
    rows, cols = valid.shape
    fy = np.fft.fftfreq(rows, d=spacing)[:, None]
    fx = np.fft.rfftfreq(cols, d=spacing)[None, :]
    radial = np.hypot(fx, fy)
    # rfft2 stores the columns 1..W/2-1 once for two conjugate halves: weight them twice.
    weight = np.full(radial.shape, 2.0)
    weight[:, 0] = 1.0
    if cols % 2 == 0:
        weight[:, -1] = 1.0
    nyquist = 0.5 / spacing
    width = bin_width if bin_width is not None else 1.0 / (min(rows, cols) * spacing)
    if not width > 0:
        raise ValueError(f"bin_width must be positive, got {bin_width}")
    index = np.floor(radial / width + 0.5).astype(np.int64)  # annulus k: (k - ½, k + ½]·width
    n_bins = int(np.floor(nyquist / width + 0.5)) + 1
    use = (index >= 1) & (index < n_bins) & (radial <= nyquist * (1 + 1e-12))
    idx = index[use]
    w = weight[use]

    def annulus_sum(values: np.ndarray) -> np.ndarray:
        return np.bincount(idx, weights=w * values[use], minlength=n_bins)

    count = np.bincount(idx, weights=w, minlength=n_bins)
    cross = annulus_sum((spec_a * np.conj(spec_b)).real)
    power_a = annulus_sum(np.abs(spec_a) ** 2)
    power_b = annulus_sum(np.abs(spec_b) ** 2)
    freq = annulus_sum(radial)
    keep = (count > 0) & (power_a > 0) & (power_b > 0)
    keep[0] = False
    count, cross, power_a, power_b, freq = (v[keep] for v in (count, cross, power_a, power_b,
                                                               freq))
    coherence = np.clip(cross**2 / (power_a * power_b), 0.0, 1.0)
    norm = (taper**2).sum() / spacing**2  # PSD normalisation (periodogram, m² per cycle²/m²)
    return CoherenceSpectrum(
        frequency=freq / count,
        coherence=coherence,
        power_dem=power_a / count / norm,
        power_reference=power_b / count / norm,
        count=np.round(count).astype(np.int64),
        window=(int(r0), int(c0), int(r1), int(c1)),
    )


def radial_coherence(dem: np.ndarray, reference: np.ndarray, *, spacing: float = 1.0,
                     window: str = "hann", nan_policy: str = "auto",
                     bin_width: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Radially averaged magnitude-squared coherence of a DEM with a reference.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid
        Two co-registered DEMs on one grid.
    spacing : float
        Pixel spacing in metres.
    window, nan_policy, bin_width
        See :func:`coherence_spectrum`.

    Returns
    -------
    frequencies : (K,) float64
        Radial frequency of each annulus, cycles per metre, increasing.
    coherence : (K,) float64
        :math:`|\\langle S_{ab}\\rangle|^2 / (\\langle S_{aa}\\rangle\\langle S_{bb}\\rangle)`
        in [0, 1] (Bendat & Piersol 2010, eq. 5.90, annulus-averaged).
    """
    result = coherence_spectrum(dem, reference, spacing=spacing, window=window,
                                nan_policy=nan_policy, bin_width=bin_width)
    return result.frequency, result.coherence


def cutoff_from_curve(frequencies: np.ndarray, coherence: np.ndarray, *,
                      threshold: float = 0.5) -> float:
    """Highest frequency up to which a coherence curve stays at or above ``threshold``.

    The crossing is found at the first annulus below the threshold and interpolated
    linearly between it and the annulus before.  Returns the last frequency when the
    curve never drops, and 0.0 when it starts below the threshold.
    """
    below = np.nonzero(coherence < threshold)[0]
    if below.size == 0:
        return float(frequencies[-1])
    k = int(below[0])
    if k == 0:
        return 0.0
    f0, f1 = frequencies[k - 1], frequencies[k]
    c0, c1 = coherence[k - 1], coherence[k]
    return float(f0 + (c0 - threshold) / (c0 - c1) * (f1 - f0))


def coherence_cutoff(dem: np.ndarray, reference: np.ndarray, *, spacing: float = 1.0,
                     threshold: float = 0.5, window: str = "hann",
                     nan_policy: str = "auto") -> float:
    """Coherent cut-off frequency: where the DEM stops agreeing with the reference.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid
        Two co-registered DEMs on one grid.
    spacing : float
        Pixel spacing in metres.
    threshold : float
        Coherence level; 0.5 is where signal and noise power are equal.
    window, nan_policy
        See :func:`coherence_spectrum`.

    Returns
    -------
    float
        Cycles per metre, in [0, 0.5 / spacing]: the highest frequency up to which the
        coherence stays at or above ``threshold`` (linear interpolation at the first
        crossing); the Nyquist frequency if it never drops.  The effective resolution
        is its inverse (a wavelength, metres).
    """
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold must be in (0, 1), got {threshold}")
    freq, coh = radial_coherence(dem, reference, spacing=spacing, window=window,
                                 nan_policy=nan_policy)
    if np.all(coh >= threshold):
        return 0.5 / spacing
    return cutoff_from_curve(freq, coh, threshold=threshold)
