"""Adjust a block of images that come with sensor models (``bundle --sensors``).

:func:`adjust_sensor_block` is the core of that route: image pairs (all, sequential or
by footprint overlap), SIFT tie points, the pose-prior bundle adjustment of
:mod:`demtool.bundle.priors`, and the result as a :class:`BundleResult` in the
body-fixed frame (metres) with a local pinhole per image (:func:`local_pinhole`) so
``bundle.npz`` readers keep working.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.bundle.model import BundleResult
from demtool.bundle.priors import AdjustedSensor, PriorAdjustment, adjust_with_priors
from demtool.bundle.ties import image_pairs, report_by_name, tie_points
from demtool.errors import ProcessingError
from demtool.logs import get_logger
from demtool.sensors.base import SensorModel
from demtool.sensors.pinhole import PinholeCamera

log = get_logger(__name__)


def local_pinhole(model: SensorModel, *, grid: int = 7) -> tuple[PinholeCamera, float]:
    """The pinhole ``x ∝ K R (X − C)`` closest to a sensor model's rays.

    ``C`` is the sensor position at the centre line; ``K R`` is fitted to the rays of a
    ``grid × grid`` set of pixels (DLT, Hartley & Zisserman 2004, sect. 7.1, on the ray
    directions) and split by an RQ decomposition.  Exact for a frame camera without
    distortion; an approximation otherwise (a line scanner's moving centre, a lens).

    Returns
    -------
    camera : PinholeCamera
        World (body-fixed, metres) to camera; demtool's pixel convention
        (``u = sample − 0.5``, ``v = line − 0.5``).
    rms_px : float
        RMS distance between the pinhole's and the model's pixels of the fitted rays.
    """
    from scipy.linalg import rq

    lines, samples = np.meshgrid(np.linspace(0.5, model.lines - 0.5, grid),
                                 np.linspace(0.5, model.samples - 0.5, grid), indexing="ij")
    ray = model.image_to_ray(lines.ravel(), samples.ravel())
    centre = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64).reshape(3)
    y = ray.origin + 1e3 * ray.direction - centre
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    u, v = samples.ravel() - 0.5, lines.ravel() - 0.5
    zeros = np.zeros_like(y)
    a = np.concatenate([np.hstack([-y, zeros, u[:, None] * y]),
                        np.hstack([zeros, -y, v[:, None] * y])])
    m = np.linalg.svd(a)[2][-1].reshape(3, 3)
    if np.linalg.det(m) < 0:
        m = -m
    k, r = rq(m)
    signs = np.diag(np.sign(np.diag(k)))
    k, r = k @ signs, signs @ r
    k /= k[2, 2]
    camera = PinholeCamera(K=k, R=r, t=-r @ centre, width=int(model.samples),
                           height=int(model.lines), name=model.name)
    projected = camera.project(ray.origin + 1e3 * ray.direction)
    rms = float(np.sqrt(np.mean(np.sum((projected - np.stack([u, v], 1)) ** 2, axis=1))))
    return camera, rms


@dataclass(frozen=True)
class SensorBlockAdjustment:
    """The outcome of :func:`adjust_sensor_block`.

    Attributes
    ----------
    result : BundleResult
        Tie points (body-fixed metres) and local pinholes of the adjusted models
        (``aligned`` True: the block is metric, in the body-fixed frame).
    adjustment : PriorAdjustment
        Pose offsets, tie points, residuals.
    adjusted : list of SensorModel
        The adjusted models, input order.
    summary : dict
        Pairs, tie points, residuals and the per-image report.
    """

    result: BundleResult
    adjustment: PriorAdjustment
    adjusted: list[SensorModel]
    summary: dict[str, Any]


def adjust_sensor_block(names: Sequence[str], images: Sequence[np.ndarray],
                        models: Sequence[SensorModel], *, pairing: str = "exhaustive",
                        position_sigma: float, pointing_sigma: float,
                        max_features: int | None = None, seed: int = 0,
                        surface=None, refine_ties: bool = True,
                        register_to_dem: bool = True) -> SensorBlockAdjustment:
    """Tie points and pose-prior bundle adjustment of images with sensor models.

    Parameters
    ----------
    names : sequence of str
        View names.
    images : sequence of (H, W) arrays
        The images (any dtype; NaN = no data), each the size of its model.
    models : sequence of SensorModel
        Prior models (body-fixed metres).
    pairing : {"exhaustive", "sequential", "spatial"}
        Pairs to match (spatial: overlapping footprints of the prior models).
    position_sigma, pointing_sigma : float
        Prior standard deviations, metres and milliradians.
    max_features : int, optional
        SIFT keypoints per image; default one per 64 px of image, 8192 to 65536
        (:func:`demtool.bundle.ties.features_per_image`).
    seed : int
        Seed of the robust matching.
    surface : demtool.bundle.surface.ReferenceSurface, optional
        A reference DEM tying the tie points' heights (the block's datum).
    refine_ties : bool
        Re-measure the SIFT tracks by affine least-squares matching
        (:mod:`demtool.bundle.tierefine`).
    register_to_dem : bool
        With ``surface``: also adjust from the prior block registered to it and keep
        the solution of lower cost (:func:`demtool.bundle.priors.adjust_with_priors`).

    Raises
    ------
    ProcessingError
        No overlapping pair, or an image without tie points.
    """
    pairs = image_pairs(len(models), pairing, models)
    if not pairs:
        raise ProcessingError("no two images overlap (footprints of the sensor models); "
                              "check the --sensors order or the images")
    log.info("matching %d image pairs (%s)", len(pairs), pairing)
    obs, ties = tie_points(images, pairs, max_features=max_features, seed=seed,
                           refine=refine_ties)
    if obs.point_count == 0:
        raise ProcessingError("no tie points between the images: they may not overlap "
                              "or lack texture (try more --max-features)")
    adjustment = adjust_with_priors(models, obs, position_sigma=position_sigma,
                                    pointing_sigma=pointing_sigma, surface=surface,
                                    register_to_dem=register_to_dem)
    adjusted = [AdjustedSensor(m, o) for m, o in zip(models, adjustment.offsets, strict=True)]
    kept = adjustment.observations
    norms = np.linalg.norm(adjustment.residuals, axis=1)
    n_points = kept.point_count
    track = np.bincount(kept.point, minlength=n_points)
    errors = np.bincount(kept.point, norms, n_points) / np.maximum(track, 1)
    colors = np.zeros(n_points)
    for i, image in enumerate(images):
        sel = kept.image == i
        rows = np.clip((kept.line[sel] - 0.5).round().astype(int), 0, image.shape[0] - 1)
        cols = np.clip((kept.sample[sel] - 0.5).round().astype(int), 0, image.shape[1] - 1)
        colors += np.bincount(kept.point[sel], np.nan_to_num(np.asarray(image, float)[rows,
                                                                                   cols]),
                              n_points)
    colors /= np.maximum(track, 1)
    cameras, fits = zip(*(local_pinhole(m) for m in adjusted), strict=True)
    result = BundleResult(points=adjustment.points, colors=colors,
                          track_length=track.astype(np.int64), reprojection_error=errors,
                          image_names=np.asarray(names, dtype=str), cameras=list(cameras),
                          distortion=np.zeros((len(names), 2)), target_index=0, aligned=True)
    images_report = adjustment.image_report(names)
    for name, fit in zip(names, fits, strict=True):
        row = images_report[name]
        row["pinhole_fit_rms_px"] = fit
        # the move from the prior in units of the prior's σ (per axis; a 3-D move of
        # 3σ along one axis reads 3)
        row["position_change_prior_sigmas"] = row["position_change_m"] / position_sigma
        row["pointing_change_prior_sigmas"] = row["pointing_change_mrad"] / pointing_sigma
    summary: dict[str, Any] = {
        "images_given": list(names),
        "registered": list(names),
        "not_registered": [],
        "registered_count": len(names),
        "image_count": len(names),
        "frame": "body-fixed, metres",
        "pairing": pairing,
        "pairs": report_by_name(ties["pairs"], names),
        "tie_refinement": ties.get("refine"),
        "points": int(n_points),
        "observations": int(len(kept.image)),
        "mean_track_length": float(track.mean()) if n_points else 0.0,
        "initial_rms_reprojection_error_px": adjustment.initial_rms_px,
        "mean_reprojection_error_px": float(norms.mean()),
        "median_reprojection_error_px": float(np.median(norms)),
        "p95_reprojection_error_px": float(np.percentile(norms, 95)),
        "position_sigma_m": position_sigma,
        "pointing_sigma_mrad": pointing_sigma,
        "target": str(names[0]),
        "images": images_report,
    }
    if surface is not None:
        dh = adjustment.surface_residuals
        on = np.isfinite(dh)
        tie_sigma = surface.point_sigmas(adjustment.points)
        summary["reference_dem"] = {
            "sigma_m": surface.sigma,
            "post_spacing_m": surface.post_m,
            "interpolation_factor": surface.slope_factor,
            "curvature_bound_median_m": None if surface.curvature is None
            else float(np.nanmedian(surface.curvature)),
            "tie_point_sigma_median_m": float(np.median(tie_sigma)),
            "tie_point_sigma_p90_m": float(np.percentile(tie_sigma, 90)),
            "points_on_dem": int(on.sum()),
            "height_residual_median_m": float(np.median(dh[on])) if on.any() else None,
            "height_residual_rms_m": float(np.sqrt(np.mean(dh[on] ** 2)))
            if on.any() else None,
        }
        shift = adjustment.surface_shift
        if shift is not None:
            summary["reference_dem"]["registration"] = {
                "east_m": shift.east_m, "north_m": shift.north_m, "up_m": shift.up_m,
                "searched_m": shift.searched_m, "spread_before_m": shift.spread_before_m,
                "spread_m": shift.spread_m, "used": shift.used}
    return SensorBlockAdjustment(result=result, adjustment=adjustment, adjusted=adjusted,
                                 summary=summary)
