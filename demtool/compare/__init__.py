"""``compare``: measure a DEM against a reference (co-registration, statistics, plots).

Pure functions (arrays in, arrays out); the command ``demtool compare`` does the I/O.

* :func:`compare_dems` — align one DEM to a reference on one grid and measure it.
* :func:`summarize` — the headline figures of a comparison (one table row).
* :mod:`~demtool.compare.grids` — resampling, shifts, reprojection.
* :mod:`~demtool.compare.coreg`, :mod:`~demtool.compare.icp`,
  :mod:`~demtool.compare.align` — co-registration.
* :mod:`~demtool.compare.stats` — error statistics; :mod:`~demtool.compare.plots` —
  figures.

Names are imported lazily (PEP 562), so ``demtool compare --help`` and the
parameter module ``demtool.compare.params`` do not pull in numba, OpenCV or pycolmap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.compare.align import (  # noqa: F401
        ALIGN_METHODS,
        Alignment,
        coregister,
    )
    from demtool.compare.core import (  # noqa: F401
        DEFAULT_SLOPE_BINS,
        Comparison,
        compare_dems,
        summarize,
    )

_EXPORTS = {
    "ALIGN_METHODS": "demtool.compare.align",
    "Alignment": "demtool.compare.align",
    "coregister": "demtool.compare.align",
    "DEFAULT_SLOPE_BINS": "demtool.compare.core",
    "Comparison": "demtool.compare.core",
    "compare_dems": "demtool.compare.core",
    "summarize": "demtool.compare.core",
}

__all__ = [
    "ALIGN_METHODS",
    "DEFAULT_SLOPE_BINS",
    "Alignment",
    "Comparison",
    "compare_dems",
    "coregister",
    "summarize",
]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'demtool.compare' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
