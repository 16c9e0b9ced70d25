"""Dense DEMs in the target image frame, from bundle points or from a disparity map.

Routes (see :mod:`demtool.dem.routes`):

* :func:`dem_from_points` — bundle points projected into the target camera, heights by
  eq. 2 of the Rosetta NavCam study (or metric when the bundle is aligned);
* :func:`dem_from_disparity_calibrated` — disparities triangulated with known cameras;
* :func:`dem_from_disparity_projective` — disparities mapped to heights by a robust 3-D
  projective fit to a reference DEM (the study's uncalibrated SIAM route).

All end with outlier removal, resampling to the target pixel grid and D'Errico's
spring-metaphor gap filling (:func:`demtool.imaging.interpolate.inpaint_springs`).

Names are imported lazily (PEP 562), so ``demtool dem --help`` and the
parameter module ``demtool.dem.params`` do not pull in numba, OpenCV or pycolmap.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "disparity": ("apply_projective_3d", "disparity_correspondences", "fit_projective_3d"),
    "grid": ("fill_and_smooth", "local_median_inliers", "splat_bilinear", "splat_median"),
    "points": ("estimate_gsd", "heights_along_view", "heights_from_relative_depth",
        "target_samples"),
    "routes": ("DemResult", "OutlierOptions", "dem_from_disparity_calibrated",
        "dem_from_disparity_projective", "dem_from_points"),
})
