"""The three routes of ``demtool dem``, from inputs in memory to a complete DEM grid.

Every route ends the same way: height samples in the target image → robust
local-median outlier test → resampling to the target pixel grid → spring-metaphor
gap filling → optional median filter.  Heights are metres, positive toward the camera.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from demtool.dem.disparity import (
    apply_projective_3d,
    disparity_correspondences,
    fit_projective_3d,
    sample_bilinear,
    triangulate,
)
from demtool.dem.grid import (
    fill_and_smooth,
    local_median_inliers,
    splat_bilinear,
    splat_median,
)
from demtool.dem.points import heights_along_view, target_samples
from demtool.errors import ProcessingError
from demtool.logs import get_logger
from demtool.sensors.pinhole import PinholeCamera

log = get_logger(__name__)

#: Fewest height samples a DEM is interpolated from.
MIN_SAMPLES = 10


@dataclass(frozen=True)
class OutlierOptions:
    """Robust local-median outlier test (see :func:`demtool.dem.grid.local_median_inliers`).

    Attributes
    ----------
    neighbours : int
        Nearest samples each sample is compared with.
    threshold : float
        Rejection threshold in local NMADs (≤ 0 disables the test).
    """

    neighbours: int = 16
    threshold: float = 3.0


@dataclass(frozen=True)
class DemResult:
    """A DEM in the target image frame.

    Attributes
    ----------
    dem : (H, W) float64
        Heights, metres, positive toward the camera; complete (no NaN).
    interpolated : (H, W) bool
        True where the height was filled rather than measured.
    measured : (H, W) float64
        The measured grid before filling (NaN where unmeasured).
    report : dict
        Counts and statistics of the route (JSON-serialisable).
    """

    dem: np.ndarray
    interpolated: np.ndarray
    measured: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)


def _check_samples(count: int, what: str) -> None:
    if count < MIN_SAMPLES:
        raise ProcessingError(f"only {count} {what} in the target image; at least "
                              f"{MIN_SAMPLES} are needed to interpolate a DEM")


def finish_dem(measured: np.ndarray, median_px: int, report: dict[str, Any]) -> DemResult:
    """Fill the measured grid (NaN = unmeasured), median-filter it, wrap it with the report."""
    filled = fill_and_smooth(measured, median_px=median_px)
    report["measured_fraction"] = float(np.mean(~filled.interpolated))
    return DemResult(dem=filled.dem, interpolated=filled.interpolated, measured=measured,
                     report=report)


def dem_from_points(points: np.ndarray, camera: PinholeCamera, *, aligned: bool,
                    distance_m: float | None = None,
                    distortion: Sequence[float] = (0.0, 0.0),
                    outliers: OutlierOptions = OutlierOptions(),
                    median_px: int = 0) -> DemResult:
    """Dense DEM from bundle points in the target frame (BAM route).

    Parameters
    ----------
    points : (N, 3) float
        Bundle points (model frame; world frame, metres, when ``aligned``).
    camera : PinholeCamera
        The target camera of the bundle; the DEM has its pixel grid.
    aligned : bool
        Metric bundle: heights along the view direction (world Z for a nadir target).
        Otherwise eq. 2 of the NavCam study with ``distance_m``.
    distance_m : float, optional
        Spacecraft–surface distance, metres (required when not aligned).
    distortion : (2,) float
        Radial distortion (k1, k2) of the target camera.
    outliers : OutlierOptions
    median_px : int
        Median filter after filling (0 = none).

    Returns
    -------
    DemResult
        ``dem`` is (camera.height, camera.width).

    Raises
    ------
    ProcessingError
        No or too few points in the target image.
    """
    samples = target_samples(points, camera, aligned=aligned, distance_m=distance_m,
                             distortion=distortion)
    _check_samples(len(samples.heights), "bundle points")
    keep = local_median_inliers(samples.pixels, samples.heights,
                                neighbours=outliers.neighbours, threshold=outliers.threshold)
    _check_samples(int(keep.sum()), "bundle points left after outlier removal")
    measured, counts = splat_median(samples.pixels[keep], samples.heights[keep],
                                    (camera.height, camera.width))
    report = {
        "points_total": int(len(points)),
        "points_in_target": int(len(samples.heights)),
        "outliers_removed": int((~keep).sum()),
        "cells_measured": int(np.isfinite(measured).sum()),
        "median_depth": float(np.median(samples.depth)),
        "height_scale": "metric (aligned bundle)" if aligned else "eq. 2 (relative depth)",
    }
    log.info("%d of %d points in the target image, %d outliers removed, %d cells measured",
             report["points_in_target"], report["points_total"], report["outliers_removed"],
             report["cells_measured"])
    return finish_dem(measured, median_px, report)


def _target_side(target: str) -> str:
    if target not in ("left", "right"):
        raise ValueError(f"target must be 'left' or 'right', got {target!r}")
    return target


def dem_from_disparity_calibrated(disparity: np.ndarray, H_left: np.ndarray,
                                  H_right: np.ndarray, left_camera: PinholeCamera,
                                  right_camera: PinholeCamera, *, target: str = "left",
                                  outliers: OutlierOptions = OutlierOptions(),
                                  median_px: int = 0,
                                  max_ray_gap: float | None = None) -> DemResult:
    """DEM from a disparity map and known cameras (calibrated triangulation).

    Points behind either camera are dropped, and so are rays that miss each other by
    more than ``max_ray_gap`` metres (default
    :func:`demtool.dem.disparity.screen_triangulation`'s); the counts are in the report.

    Parameters
    ----------
    disparity : (Hr, Wr) float
        Left rectified frame, ``x_right = x_left − d``, NaN = invalid.
    H_left, H_right : (3, 3) float
        Rectification homographies (original → rectified).
    left_camera, right_camera : PinholeCamera
        Cameras of the original images (world frame, metres).
    target : {"left", "right"}
        Whose image frame the DEM is in.

    Returns
    -------
    DemResult
        Heights along the target's view direction, metres (world Z for a nadir target).
    """
    from demtool.dem.disparity import screen_triangulation

    side = _target_side(target)
    corr = disparity_correspondences(disparity, H_left, H_right)
    points, ray_distance = triangulate(corr, left_camera, right_camera)
    target_camera = left_camera if side == "left" else right_camera
    heights = heights_along_view(points, target_camera)
    pixels = corr.left if side == "left" else corr.right
    ok = np.isfinite(heights) & np.isfinite(pixels).all(axis=1)
    screen = screen_triangulation(points, ray_distance, left_camera, right_camera,
                                  max_ray_gap=max_ray_gap)
    ok &= screen.keep
    _check_samples(int(ok.sum()), "triangulated disparities in front of both cameras")
    pixels, heights, ray_distance = pixels[ok], heights[ok], ray_distance[ok]
    keep = local_median_inliers(pixels, heights, neighbours=outliers.neighbours,
                                threshold=outliers.threshold)
    measured, _ = splat_bilinear(pixels[keep], heights[keep],
                                 (target_camera.height, target_camera.width))
    report = {
        "disparities": int(len(corr.rectified)),
        "behind_camera": screen.behind,
        "max_ray_gap_m": screen.max_gap,
        "rejected_ray_gap": screen.rejected_gap,
        "outliers_removed": int((~keep).sum()),
        "ray_distance_median_m": float(np.median(ray_distance)),
        "median_depth_m": float(np.median(target_camera.depth(points[ok]))),
        "cells_measured": int(np.isfinite(measured).sum()),
    }
    log.info("%d disparities triangulated: %d behind a camera and %d rays missing by more "
             "than %.3g m dropped (median ray gap %.3g m), %d outliers removed",
             report["disparities"], screen.behind, screen.rejected_gap, screen.max_gap,
             report["ray_distance_median_m"], report["outliers_removed"])
    return finish_dem(measured, median_px, report)


def dem_from_disparity_projective(disparity: np.ndarray, H_left: np.ndarray,
                                  H_right: np.ndarray, reference: np.ndarray, *,
                                  target: str = "left",
                                  outliers: OutlierOptions = OutlierOptions(),
                                  median_px: int = 0, seed: int = 0) -> DemResult:
    """DEM from a disparity map by a projective fit to a reference DEM (uncalibrated).

    The SIAM route of the NavCam study: the 3-D projective transformation that best
    maps (x, y, d) — left rectified pixel and disparity — to (x, y, h) — target pixel
    and reference height — is fitted robustly (:func:`fit_projective_3d`); it then
    gives the height of every disparity.  A projective reconstruction from an
    uncalibrated pair differs from the Euclidean one by exactly such a transformation
    (Hartley & Zisserman 2004, §10.2).

    Parameters
    ----------
    disparity : (Hr, Wr) float
    H_left, H_right : (3, 3) float
    reference : (H, W) float
        Reference heights on the target image's pixel grid (e.g. the BAM DEM),
        metres, NaN where unknown.
    target : {"left", "right"}
    seed : int
        Seed of the robust search.

    Returns
    -------
    DemResult
        Heights in the reference's vertical datum and units.
    """
    side = _target_side(target)
    corr = disparity_correspondences(disparity, H_left, H_right)
    pixels = corr.left if side == "left" else corr.right
    reference_heights = sample_bilinear(reference, pixels)
    usable = np.isfinite(reference_heights) & np.isfinite(pixels).all(axis=1)
    if usable.sum() < 5 * MIN_SAMPLES:
        raise ProcessingError(f"only {int(usable.sum())} disparities fall on valid reference "
                              f"heights; the reference must cover the target image")
    target_points = np.column_stack([pixels, reference_heights])
    fit = fit_projective_3d(corr.rectified[usable], target_points[usable], seed=seed)
    heights = apply_projective_3d(fit.T, corr.rectified)[:, 2]
    ok = np.isfinite(heights) & np.isfinite(pixels).all(axis=1)
    _check_samples(int(ok.sum()), "mapped disparities")
    pixels, heights = pixels[ok], heights[ok]
    keep = local_median_inliers(pixels, heights, neighbours=outliers.neighbours,
                                threshold=outliers.threshold)
    measured, _ = splat_bilinear(pixels[keep], heights[keep], reference.shape)
    report = {
        "disparities": int(len(corr.rectified)),
        "fit_points": int(usable.sum()),
        "fit_inliers": int(fit.inliers.sum()),
        "fit_residual_nmad_m": fit.residual_nmad,
        "projective_transform": fit.T.tolist(),
        "outliers_removed": int((~keep).sum()),
        "cells_measured": int(np.isfinite(measured).sum()),
    }
    log.info("projective fit on %d disparities: %d inliers, height residual NMAD %.3g",
             report["fit_points"], report["fit_inliers"], fit.residual_nmad)
    return finish_dem(measured, median_px, report)
