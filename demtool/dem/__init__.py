"""Dense DEMs in the target image frame, from bundle points or from a disparity map.

Routes (see :mod:`demtool.dem.routes`):

* :func:`dem_from_points` — bundle points projected into the target camera, heights by
  eq. 2 of the Rosetta NavCam study (or metric when the bundle is aligned);
* :func:`dem_from_disparity_calibrated` — disparities triangulated with known cameras;
* :func:`dem_from_disparity_projective` — disparities mapped to heights by a robust 3-D
  projective fit to a reference DEM (the study's uncalibrated SIAM route).

All end with outlier removal, resampling to the target pixel grid and D'Errico's
spring-metaphor gap filling (:func:`demtool.interpolate.inpaint_springs`).
"""

from demtool.dem.disparity import (
    apply_projective_3d,
    disparity_correspondences,
    fit_projective_3d,
)
from demtool.dem.grid import (
    fill_and_smooth,
    local_median_inliers,
    splat_bilinear,
    splat_median,
)
from demtool.dem.points import (
    estimate_gsd,
    heights_along_view,
    heights_from_relative_depth,
    target_samples,
)
from demtool.dem.routes import (
    DemResult,
    OutlierOptions,
    dem_from_disparity_calibrated,
    dem_from_disparity_projective,
    dem_from_points,
)

__all__ = [
    "DemResult",
    "OutlierOptions",
    "apply_projective_3d",
    "dem_from_disparity_calibrated",
    "dem_from_disparity_projective",
    "dem_from_points",
    "disparity_correspondences",
    "estimate_gsd",
    "fill_and_smooth",
    "fit_projective_3d",
    "heights_along_view",
    "heights_from_relative_depth",
    "local_median_inliers",
    "splat_bilinear",
    "splat_median",
    "target_samples",
]
