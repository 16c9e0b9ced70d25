"""``compare``: measure a DEM against a reference (co-registration, statistics, plots).

Pure functions (arrays in, arrays out); the command ``demtool compare`` does the I/O.

* :func:`compare_dems` — align one DEM to a reference on one grid and measure it.
* :func:`summarize` — the headline figures of a comparison (one table row).
* :mod:`~demtool.compare.grids` — resampling, shifts, reprojection.
* :mod:`~demtool.compare.coreg`, :mod:`~demtool.compare.icp`,
  :mod:`~demtool.compare.align` — co-registration.
* :mod:`~demtool.compare.stats` — error statistics; :mod:`~demtool.compare.plots` —
  figures.
"""

from demtool.compare.align import ALIGN_METHODS, Alignment, coregister
from demtool.compare.core import DEFAULT_SLOPE_BINS, Comparison, compare_dems, summarize

__all__ = [
    "ALIGN_METHODS",
    "DEFAULT_SLOPE_BINS",
    "Alignment",
    "Comparison",
    "compare_dems",
    "coregister",
    "summarize",
]
