"""The comparison of one DEM with a reference on one grid: align, measure, summarise."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.compare.align import ALIGN_METHODS, Alignment, coregister
from demtool.compare.stats import (
    completeness,
    difference_statistics,
    slope_class_statistics,
    slope_degrees,
)
from demtool.compare.threads import Side, threaded
from demtool.errors import ParameterError, ProcessingError
from demtool.imaging.spectral import CoherenceSpectrum, coherence_spectrum, cutoff_from_curve
from demtool.logs import get_logger

__all__ = ["DEFAULT_SLOPE_BINS", "Comparison", "compare_dems", "summarize"]

log = get_logger(__name__)

DEFAULT_SLOPE_BINS = (0.0, 5.0, 10.0, 20.0, 30.0, 90.0)


@dataclass
class Comparison:
    """Everything one comparison produced (arrays on the comparison grid).

    Attributes
    ----------
    report : dict
        The figures (see :func:`compare_dems`), JSON-ready.
    aligned : (H, W) float64
        The DEM after co-registration, metres, NaN = no value.
    reference : (H, W) float64
        The reference, metres.
    difference : (H, W) float64
        ``aligned − reference`` (NaN outside the common valid pixels and the mask).
    coverage : (H, W) float32
        Completeness map: 1 DEM has a value, 0 it lacks one, NaN outside the reference.
    slope : (H, W) float64
        Slope of the reference, degrees.
    alignment : Alignment
    spectrum : CoherenceSpectrum or None
        None when the common area is too small for a spectrum.
    """

    report: dict[str, Any]
    aligned: np.ndarray
    reference: np.ndarray
    difference: np.ndarray
    coverage: np.ndarray
    slope: np.ndarray
    alignment: Alignment
    spectrum: CoherenceSpectrum | None


def _spacing_pair(spacing: float | Sequence[float]) -> tuple[float, float]:
    if np.isscalar(spacing):
        pair = (float(spacing), float(spacing))  # type: ignore[arg-type]
    else:
        pair = tuple(float(s) for s in spacing)  # type: ignore[union-attr]
    if len(pair) != 2 or not all(np.isfinite(s) and s > 0 for s in pair):
        raise ParameterError(f"spacing must be one or two positive numbers, got {spacing}")
    return pair  # type: ignore[return-value]


def effective_resolution(spectrum: CoherenceSpectrum, spacing: float,
                         threshold: float = 0.5) -> dict[str, Any]:
    """The coherent cut-off of a spectrum as a report entry.

    Returns ``coherent_frequency_per_m``, ``wavelength_m`` (its inverse; None when the
    coherence starts below the threshold), ``nyquist_limited`` (True when the
    coherence never drops: the DEM is coherent up to the grid's Nyquist frequency and
    the wavelength is the grid's limit, two pixels), ``threshold`` and the curve.
    """
    below = spectrum.coherence < threshold
    if not below.any():
        frequency = 0.5 / spacing
    else:
        frequency = cutoff_from_curve(spectrum.frequency, spectrum.coherence,
                                      threshold=threshold)
    return {
        "coherent_frequency_per_m": frequency,
        "wavelength_m": 1.0 / frequency if frequency > 0 else None,
        "nyquist_limited": bool(not below.any()),
        "threshold": threshold,
        "window_rows_cols": list(spectrum.window),
        "frequency_per_m": spectrum.frequency.tolist(),
        "coherence": spectrum.coherence.tolist(),
    }


def compare_dems(dem: np.ndarray, reference: np.ndarray, *,
                 spacing: float | Sequence[float] = 1.0, align: str = "nuth-kaab",
                 mask: np.ndarray | None = None,
                 slope_bins: Sequence[float] = DEFAULT_SLOPE_BINS, icp_scale: bool = False,
                 coherence_threshold: float = 0.5, seed: int = 0) -> Comparison:
    """Co-register a DEM to a reference and measure their differences.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid, on one grid
        The DEM to judge and the reference (e.g. the truth).  Not modified.
    spacing : float or (float, float)
        Pixel size (x, y) of the grid, metres.
    align : str
        Co-registration, one of ``none``, ``offset``, ``nuth-kaab``, ``icp``,
        ``nuth-kaab+icp`` (see :func:`demtool.compare.align.coregister`).
    mask : (H, W) bool, optional
        True on the pixels to fit and measure (e.g. stable terrain).
    slope_bins : sequence of float
        Edges of the slope classes, degrees, increasing.
    icp_scale : bool
        Let ICP fit a scale too.
    coherence_threshold : float
        Coherence level defining the effective resolution.
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    Comparison
        ``report`` has the top-level keys ``count``, ``completeness`` (percent),
        ``mean``, ``median``, ``std``, ``rmse``, ``nmad``, ``le90``, ``min``, ``max``
        (metres, of DEM − reference after alignment, over the common valid pixels in
        the mask), ``shift`` and ``shift_uncertainty`` (``dx_px``, ``dy_px``, ``dz``:
        what was added to the DEM), ``alignment`` (the steps), ``before_alignment``
        (the statistics without co-registration), ``slope_classes``,
        ``effective_resolution`` and ``warnings``.

    Raises
    ------
    ProcessingError
        No common valid pixel, or too few for the alignment.
    ParameterError
        Bad ``align``, ``spacing`` or ``slope_bins``.
    """
    dem = np.asarray(dem, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if dem.shape != reference.shape or dem.ndim != 2:
        raise ValueError(f"dem and reference must be 2-D arrays of one shape, got "
                         f"{dem.shape} and {reference.shape}")
    if align not in ALIGN_METHODS:
        raise ParameterError(f"unknown alignment {align!r}: should be one of "
                             + ", ".join(ALIGN_METHODS))
    bins = np.asarray(slope_bins, dtype=np.float64)
    if bins.ndim != 1 or bins.size < 2 or np.any(np.diff(bins) <= 0):
        raise ParameterError(f"slope bins must be at least two increasing values, got "
                             f"{list(slope_bins)}")
    sx, sy = _spacing_pair(spacing)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != dem.shape:
            raise ValueError(f"mask has shape {mask.shape}, DEM has {dem.shape}")
    common = np.isfinite(dem) & np.isfinite(reference)
    if mask is not None:
        common &= mask
    if not common.any():
        raise ProcessingError("the DEM and the reference have no common valid pixel"
                              + (" inside the mask" if mask is not None else ""))
    with Side(threaded(dem.size)) as side:
        return _compare(side, dem, reference, mask, align, (sx, sy), bins, icp_scale,
                        coherence_threshold, seed)


def _compare(side, dem, reference, mask, align, spacing, bins, icp_scale,
             coherence_threshold, seed) -> Comparison:
    """:func:`compare_dems` after its checks; what does not need the alignment (the
    completeness, the statistics before it, the slopes) runs on the ``side`` thread
    (:class:`demtool.compare.threads.Side`) while this one aligns, and the coherence
    spectrum (itself on two threads) while this one measures the aligned difference
    (numpy and the FFT release the GIL; the same functions on the same arrays give the
    same numbers)."""
    sx, sy = spacing

    def unaligned() -> tuple[Any, ...]:
        return (*completeness(dem, reference, mask), difference_statistics(dem - reference,
                                                                           mask),
                slope_degrees(reference, (sx, sy)))

    independent = side.later(unaligned)
    try:
        aligned, alignment = coregister(dem, reference, method=align, spacing=(sx, sy),
                                        mask=mask, icp_scale=icp_scale, seed=seed)
    except ProcessingError as exc:
        # a DEM too sparse or too flat to align is still measured, unaligned, with a warning
        aligned, alignment = coregister(dem, reference, method="none")
        alignment.warnings.append(f"alignment '{align}' failed, statistics are unaligned: "
                                  f"{exc}")
        log.warning("alignment '%s' failed, statistics are unaligned: %s", align, exc)

    def spectral() -> tuple[CoherenceSpectrum | None, dict[str, Any] | None, str | None]:
        try:
            masked_aligned = aligned if mask is None else np.where(mask, aligned, np.nan)
            spectrum = coherence_spectrum(masked_aligned, reference,
                                          spacing=float(np.sqrt(sx * sy)),
                                          threads=2 if threaded(reference.size) else 1)
            return spectrum, effective_resolution(spectrum, float(np.sqrt(sx * sy)),
                                                  coherence_threshold), None
        except ProcessingError as exc:
            return None, None, str(exc)

    spectral_parts = side.later(spectral)
    difference = aligned - reference
    if mask is not None:
        difference = np.where(mask, difference, np.nan)
    after = difference_statistics(difference)
    percent, coverage, before, slope = independent.result()
    slope_classes = slope_class_statistics(difference, slope, bins)
    warnings = list(alignment.warnings)
    spectrum, resolution, failure = spectral_parts.result()
    if failure is not None:
        warnings.append(f"no effective resolution: {failure}")
        log.warning("no effective resolution: %s", failure)
    report: dict[str, Any] = {
        **{k: after[k] for k in ("count", "mean", "median", "std", "rmse", "nmad", "le90",
                                 "min", "max")},
        "completeness": percent,
        "shift": dict(alignment.shift),
        "shift_uncertainty": dict(alignment.shift_uncertainty),
        "alignment": alignment.as_dict(),
        "before_alignment": before,
        "slope_classes": slope_classes,
        "effective_resolution": resolution,
        "grid": {"shape": list(reference.shape), "spacing_m": [sx, sy]},
        "warnings": warnings,
    }
    return Comparison(report=report, aligned=aligned, reference=reference,
                      difference=difference, coverage=coverage, slope=slope,
                      alignment=alignment, spectrum=spectrum)


def summarize(dem: np.ndarray, reference: np.ndarray, *,
              spacing: float | Sequence[float] = 1.0, align: str = "nuth-kaab",
              mask: np.ndarray | None = None) -> dict[str, Any]:
    """Headline figures of a comparison, for a one-row-per-product table.

    Parameters
    ----------
    dem, reference, spacing, align, mask
        As in :func:`compare_dems`.

    Returns
    -------
    dict
        ``rmse``, ``nmad``, ``mean``, ``median``, ``le90`` (metres), ``completeness``
        (percent), ``count``, ``coherent_frequency_per_m``, ``wavelength_m``,
        ``dx_px``, ``dy_px``, ``dz`` (the applied shift) and ``warnings``.
    """
    comparison = compare_dems(dem, reference, spacing=spacing, align=align, mask=mask)
    report = comparison.report
    resolution = report["effective_resolution"] or {}
    return {
        **{k: report[k] for k in ("rmse", "nmad", "mean", "median", "le90", "completeness",
                                  "count")},
        "coherent_frequency_per_m": resolution.get("coherent_frequency_per_m"),
        "wavelength_m": resolution.get("wavelength_m"),
        **report["shift"],
        "warnings": report["warnings"],
    }
