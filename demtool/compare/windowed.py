"""The comparison of one window of a DEM larger than memory (arrays in, arrays out).

:func:`demtool.compare.run_windowed.compare_windowed` reads the DEM, the reference and
the mask window by window, resampled onto the comparison grid, and calls
:func:`window_values` on each; what it returns is what :func:`demtool.compare.compare_dems`
computes on the whole grid, restricted to the window's core:

- the aligned DEM: the co-registration found on the whole (or decimated) grid applied to
  the window — ``offset``: ``dem + dz``; ``nuth-kaab``: :func:`demtool.compare.grids.shift_dem`
  (Lanczos-3, separable), whose taps reach :func:`shift_margin` cells, so a window read
  with that margin gives the whole grid's values in its core, bit for bit;
- the slope of the reference (central differences: a 1-cell margin);
- the differences after and before alignment, the slope classes and the completeness
  counts, ready for :class:`demtool.compare.streaming.StreamStatistics`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from demtool.compare.grids import shift_dem
from demtool.compare.stats import slope_degrees

__all__ = ["WINDOWED_METHODS", "WindowValues", "shift_margin", "window_values"]

#: alignments the windowed comparison applies (ICP's rotation and scale need the whole grid)
WINDOWED_METHODS = ("none", "offset", "nuth-kaab")
LANCZOS_LOBES = 3  # shift_dem's default kernel


def shift_margin(dx_px: float, dy_px: float) -> int:
    """Cells a window needs around its core so that the shifted core and the reference's
    slope are those of the whole grid: the Lanczos taps (integer shift + lobes + 1) and the
    slope's neighbour."""
    return int(math.ceil(max(abs(dx_px), abs(dy_px)))) + LANCZOS_LOBES + 2


@dataclass
class WindowValues:
    """One window's core (arrays of the core's shape, float64 unless stated).

    aligned : the DEM after co-registration; reference : the reference; difference :
    aligned − reference, NaN outside the mask; before : DEM − reference, NaN outside the
    mask; slope : the reference's, degrees; coverage : float32, 1 / 0 the DEM has / lacks
    a value, NaN outside the reference or the mask; considered, covered : int, the
    completeness counts.
    """

    aligned: np.ndarray
    reference: np.ndarray
    difference: np.ndarray
    before: np.ndarray
    slope: np.ndarray
    coverage: np.ndarray
    considered: int
    covered: int

    def slope_classes(self, bins: Sequence[float]) -> list[np.ndarray]:
        """The finite differences in each slope class (as
        :func:`demtool.compare.stats.slope_class_statistics`: the last class includes its
        upper edge)."""
        return self.slope_parts(bins)[0]

    def slope_parts(self, bins: Sequence[float]) -> tuple[list[np.ndarray], np.ndarray]:
        """:meth:`slope_classes`, and the finite differences in none of them (a slope
        outside the bins or unknown); ``bins`` increasing, so each finite difference is
        in exactly one of the arrays."""
        edges = np.asarray(bins, dtype=np.float64)
        finite = np.isfinite(self.difference)
        unclassified = finite.copy()
        out = []
        for index, (low, high) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
            with np.errstate(invalid="ignore"):
                upper = self.slope <= high if index == len(edges) - 2 else self.slope < high
                in_class = (self.slope >= low) & upper & finite
            out.append(self.difference[in_class])
            unclassified &= ~in_class
        return out, self.difference[unclassified]


def window_values(dem: np.ndarray, reference: np.ndarray, mask: np.ndarray | None,
                  crop: tuple[slice, slice], *, method: str, shift: dict[str, float],
                  spacing: tuple[float, float]) -> WindowValues:
    """A window's comparison values (see the module docstring).

    Parameters
    ----------
    dem, reference : (h, w) float, metres, NaN = invalid
        The window with its margins, on the comparison grid.
    mask : (h, w) bool or None
        True on the cells to measure.
    crop : (slice, slice)
        The core inside the window.
    method : str
        One of :data:`WINDOWED_METHODS`.
    shift : dict
        ``dx_px``, ``dy_px`` (comparison-grid cells), ``dz`` (metres) to apply.
    spacing : (float, float)
        Cell size (x, y), metres.

    Returns
    -------
    WindowValues
    """
    dem = np.asarray(dem, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if method == "nuth-kaab":
        aligned = shift_dem(dem, shift["dx_px"], shift["dy_px"], shift["dz"])
    elif method == "offset":
        aligned = dem + shift["dz"]
    elif method == "none":
        aligned = dem
    else:
        raise ValueError(f"unknown windowed alignment {method!r}")
    slope = slope_degrees(reference, spacing)[crop]
    dem, reference, aligned = dem[crop], reference[crop], aligned[crop]
    difference = aligned - reference
    before = dem - reference
    considered = np.isfinite(reference)
    if mask is not None:
        mask = mask[crop]
        difference = np.where(mask, difference, np.nan)
        before = np.where(mask, before, np.nan)
        considered &= mask
    has_value = np.isfinite(dem)
    coverage = np.where(considered, has_value.astype(np.float32), np.float32(np.nan))
    return WindowValues(aligned=aligned, reference=reference, difference=difference,
                        before=before, slope=slope,
                        coverage=coverage.astype(np.float32),
                        considered=int(considered.sum()),
                        covered=int((has_value & considered).sum()))
