"""Shape-from-shading refinement of a coarse DEM (the core of ``demtool refine``).

Pure functions, arrays in and arrays out:

* :func:`refine_heights` — the SfS energy minimisation (:mod:`demtool.refine.sfs`);
* :func:`prepare_dem` — gap filling and median prefilter of the coarse DEM;
* :func:`estimate_albedo`, :func:`shadow_mask`, :func:`make_illumination` — the
  photometric pieces, usable on their own.

Names are imported lazily, so ``demtool.refine.params`` (used by the command line)
does not pull in numba.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "albedo": ("estimate_albedo",),
    "sfs": ("Energies", "RefineResult", "refine_heights"),
    "params": ("SfsParameters", "RefineParams"),
    "shading": ("Illumination", "make_illumination", "reflectance_map", "render_dem", "slopes",
        "sun_from_angles"),
    "shadows": ("cast_shadows", "dark_pixels", "shadow_mask"),
})
