"""``sgm --prior-dem``: the checks and reading around :mod:`demtool.sgm.prior`."""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np


class Prior(NamedTuple):
    """The disparity a prior DEM predicts on the left rectified canvas."""

    disparity: np.ndarray  # (H, W) float64 pixels, NaN outside the left image
    summary: dict[str, Any]


def read_prior(prior_dem: str | os.PathLike, rectify: str | os.PathLike | None,
               left_valid: np.ndarray, search_px: int, log) -> Prior:
    """The prior's disparity for the pair of ``rectify`` (a calibrated rectify.npz).

    Refuses (ParameterError / InputError naming the file) a pair without sensor models, one
    in a local frame, a DEM of another body or not on the body's map, and a DEM that covers
    none of the left image.  Where the DEM stops short of the image, the nearest predicted
    disparity is used (logged with the share it covers).
    """
    from demtool import io as dio
    from demtool.dem.inputs import (
        geometry_from_rectification,
        is_calibrated,
        models_from_rectification,
    )
    from demtool.errors import InputError, ParameterError
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.surface import read_dem_surface
    from demtool.maps import xyz_to_lonlat_height
    from demtool.sgm.prior import extend_nearest, prior_against_matches, prior_disparity

    if rectify is None:
        raise ParameterError(f"--prior-dem {prior_dem}: give the pair's --rectify RECTIFY_NPZ "
                             "(calibrated: rectify --sensor-left/--sensor-right)")
    rectification = dio.read_npz(rectify, "rectification")
    if not is_calibrated(rectification):
        raise ParameterError(f"--prior-dem {prior_dem}: {rectify} has no sensor models "
                             "(rectified from matches); a prior DEM needs a pair rectified "
                             "with rectify --sensor-left/--sensor-right")
    left, right = models_from_rectification(rectification, rectify)
    if left.radii is None:
        raise ParameterError(f"--prior-dem {prior_dem}: the models in {rectify} are in a local "
                             "frame, not on a body's map")
    body = sensor_body(left)
    surface = read_dem_surface(prior_dem, rectify, body)
    geometry = geometry_from_rectification(rectification, left, right)
    radius = float(body.radius)

    def heights_at(xyz: np.ndarray) -> np.ndarray:
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=radius)
        return surface.heights_lonlat(lon, lat)

    predicted = prior_disparity(geometry, left_valid.shape, radius, heights_at)
    covered = np.isfinite(predicted) & left_valid
    coverage = float(covered.sum() / max(int(left_valid.sum()), 1))
    if not covered.any():
        raise InputError(f"{prior_dem}: the prior DEM covers none of the left image of "
                         f"{rectify}")
    if coverage < 0.999:
        log.warning("%s covers %.1f %% of the left image; the nearest predicted disparity "
                    "centres the search elsewhere", prior_dem, 100 * coverage)
    check = prior_against_matches(predicted, rectification["points_left_rect"],
                                  rectification["points_right_rect"], search_px)
    correction = _judge(prior_dem, rectify, check, search_px, log)
    disparity = extend_nearest(predicted, left_valid) + correction
    disparity[~left_valid] = np.nan
    summary = {"prior_dem": str(prior_dem), "prior_coverage_fraction": round(coverage, 4),
               "prior_check_matches": check.matches,
               "prior_offset_px": None if check.matches == 0 else round(check.offset_px, 3),
               "prior_spread_px": None if check.matches == 0 else round(check.spread_px, 3),
               "prior_correction_px": round(correction, 3),
               "prior_search_px": search_px,
               "prior_disparity_range_px": [float(np.nanmin(disparity)),
                                            float(np.nanmax(disparity))]}
    log.info("prior DEM %s: predicted disparity %.1f … %.1f px; residual searched within "
             "± %d px", prior_dem, *summary["prior_disparity_range_px"], search_px)
    return Prior(disparity=disparity, summary=summary)


def _judge(prior_dem, rectify, check, search_px: int, log) -> float:
    """The correction (pixels, added to the predicted disparity) that the pair's own
    matches ask of the prior, or a refusal (issue 46: a prior 30 m / 18 px off steered the
    search to a DEM 12.4 m high; an orthoimage given as the prior, RMSE 7.2 m).

    - the matches scatter about the prediction by more than half the search (NMAD > half
      of ± search: two NMAD, most of a good prior's matches, would not fit in the search),
      or fewer than half lie within it: not a DEM of this pair's area — refused;
    - they agree in shape but sit off by more than half the search: the prior is moved
      by their median offset (a warning says how much);
    - fewer than :data:`demtool.sgm.prior.MIN_CHECK_MATCHES` on the prior: taken as given.
    """
    from demtool.errors import InputError
    from demtool.sgm.prior import MIN_CHECK_MATCHES

    if check.matches < MIN_CHECK_MATCHES:
        log.info("%s: %d of the pair's matches lie on the prior, too few to check it; "
                 "taken as given", prior_dem, check.matches)
        return 0.0
    if check.spread_px > 0.5 * search_px or check.within < 0.5:
        raise InputError(f"{prior_dem}: disagrees with the {check.matches} matches of "
                         f"{rectify} (their disparity minus the prior's: median "
                         f"{check.offset_px:+.3g} px, NMAD {check.spread_px:.3g} px, "
                         f"{100 * check.within:.0f} % within the ± {search_px} px search): "
                         "not a DEM of this pair's area (an image?); give a DEM of it")
    if abs(check.offset_px) > 0.5 * search_px:
        log.warning("%s: the pair's %d matches put the prior's disparity off by %+.3g px "
                    "(median; NMAD %.3g px), more than half the ± %d px search: the prior "
                    "is moved by that much", prior_dem, check.matches, check.offset_px,
                    check.spread_px, search_px)
        return float(check.offset_px)
    log.info("%s: the pair's %d matches agree with the prior within %+.3g px (median; "
             "NMAD %.3g px)", prior_dem, check.matches, check.offset_px, check.spread_px)
    return 0.0
