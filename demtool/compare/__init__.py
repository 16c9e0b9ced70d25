"""``compare``: measure a DEM against a reference (co-registration, statistics, plots).

Pure functions (arrays in, arrays out); the command ``demtool compare`` does the I/O.

* :func:`compare_dems` — align one DEM to a reference on one grid and measure it.
* :func:`summarize` — the headline figures of a comparison (one table row).
* :mod:`~demtool.compare.grids` — resampling, shifts, reprojection;
  :mod:`~demtool.compare.shifts` — the separable-kernel (Gaussian, Lanczos) shifts.
* :mod:`~demtool.compare.coreg`, :mod:`~demtool.compare.icp`,
  :mod:`~demtool.compare.align` — co-registration.
* :mod:`~demtool.compare.stats` — error statistics; :mod:`~demtool.compare.plots` —
  figures.

Names are imported lazily (PEP 562), so ``demtool compare --help`` and the
parameter module ``demtool.compare.params`` do not pull in numba, OpenCV or pycolmap.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "align": ("ALIGN_METHODS", "Alignment", "coregister"),
    "core": ("DEFAULT_SLOPE_BINS", "Comparison", "compare_dems", "summarize"),
})
