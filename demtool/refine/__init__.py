"""Shape-from-shading refinement of a coarse DEM (the core of ``demtool refine``).

Pure functions, arrays in and arrays out:

* :func:`refine_heights` — the SfS energy minimisation (:mod:`demtool.refine.sfs`);
* :func:`prepare_dem` — gap filling and median prefilter of the coarse DEM;
* :func:`estimate_albedo`, :func:`shadow_mask`, :func:`make_illumination` — the
  photometric pieces, usable on their own.

Names are imported lazily, so ``demtool.refine.params`` (used by the command line)
does not pull in numba.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "estimate_albedo": "demtool.refine.albedo",
    "Energies": "demtool.refine.sfs",
    "RefineResult": "demtool.refine.sfs",
    "refine_heights": "demtool.refine.sfs",
    "SfsParameters": "demtool.refine.params",
    "RefineParams": "demtool.refine.params",
    "Illumination": "demtool.refine.shading",
    "make_illumination": "demtool.refine.shading",
    "reflectance_map": "demtool.refine.shading",
    "render_dem": "demtool.refine.shading",
    "slopes": "demtool.refine.shading",
    "sun_from_angles": "demtool.refine.shading",
    "cast_shadows": "demtool.refine.shadows",
    "dark_pixels": "demtool.refine.shadows",
    "shadow_mask": "demtool.refine.shadows",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'demtool.refine' has no attribute {name!r}")


def __dir__() -> list[str]:
    return __all__
