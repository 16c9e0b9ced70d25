"""Shape-from-shading refinement of a coarse DEM (the core of ``demtool refine``).

Pure functions, arrays in and arrays out:

* :func:`refine_heights` — the SfS energy minimisation (:mod:`demtool.refine.sfs`);
* :func:`prepare_dem` — gap filling and median prefilter of the coarse DEM;
* :func:`estimate_albedo`, :func:`shadow_mask`, :func:`make_illumination` — the
  photometric pieces, usable on their own.
"""

from demtool.refine.albedo import estimate_albedo
from demtool.refine.sfs import Energies, RefineResult, SfsParameters, refine_heights
from demtool.refine.shading import (
    Illumination,
    make_illumination,
    reflectance_map,
    render_dem,
    slopes,
    sun_from_angles,
)
from demtool.refine.shadows import cast_shadows, dark_pixels, shadow_mask

__all__ = [
    "Energies", "Illumination", "RefineResult", "SfsParameters", "cast_shadows",
    "dark_pixels", "estimate_albedo", "make_illumination", "refine_heights",
    "reflectance_map", "render_dem", "shadow_mask", "slopes", "sun_from_angles",
]
