"""Dense DEMs in the target image frame, from bundle points or from a disparity map.

Routes (see :mod:`demtool.dem.routes`):

* :func:`dem_from_points` — bundle points projected into the target camera, heights by
  eq. 2 of the Rosetta NavCam study (or metric when the bundle is aligned);
* :func:`dem_from_disparity_calibrated` — disparities triangulated with known cameras;
* :func:`dem_from_disparity_projective` — disparities mapped to heights by a robust 3-D
  projective fit to a reference DEM (the study's uncalibrated SIAM route).

All end with outlier removal, resampling to the target pixel grid and D'Errico's
spring-metaphor gap filling (:func:`demtool.interpolate.inpaint_springs`).

Names are imported lazily (PEP 562), so ``demtool dem --help`` and the
parameter module ``demtool.dem.params`` do not pull in numba, OpenCV or pycolmap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.dem.disparity import (  # noqa: F401
        apply_projective_3d,
        disparity_correspondences,
        fit_projective_3d,
    )
    from demtool.dem.grid import (  # noqa: F401
        fill_and_smooth,
        local_median_inliers,
        splat_bilinear,
        splat_median,
    )
    from demtool.dem.points import (  # noqa: F401
        estimate_gsd,
        heights_along_view,
        heights_from_relative_depth,
        target_samples,
    )
    from demtool.dem.routes import (  # noqa: F401
        DemResult,
        OutlierOptions,
        dem_from_disparity_calibrated,
        dem_from_disparity_projective,
        dem_from_points,
    )

_EXPORTS = {
    "apply_projective_3d": "demtool.dem.disparity",
    "disparity_correspondences": "demtool.dem.disparity",
    "fit_projective_3d": "demtool.dem.disparity",
    "fill_and_smooth": "demtool.dem.grid",
    "local_median_inliers": "demtool.dem.grid",
    "splat_bilinear": "demtool.dem.grid",
    "splat_median": "demtool.dem.grid",
    "estimate_gsd": "demtool.dem.points",
    "heights_along_view": "demtool.dem.points",
    "heights_from_relative_depth": "demtool.dem.points",
    "target_samples": "demtool.dem.points",
    "DemResult": "demtool.dem.routes",
    "OutlierOptions": "demtool.dem.routes",
    "dem_from_disparity_calibrated": "demtool.dem.routes",
    "dem_from_disparity_projective": "demtool.dem.routes",
    "dem_from_points": "demtool.dem.routes",
}

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


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'demtool.dem' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
