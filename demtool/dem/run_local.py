"""Local-frame branch of ``demtool dem``: a calibrated pair with no body (rover, lander,
lab rig, drone) triangulated in its models' frame and gridded along an up axis.

Called by :func:`demtool.dem.run_sensors.run_dem_sensors` when the calibrated
``rectify.npz`` carries models without a body (``.tsai`` without radii, ``cameras.npz``,
OpenCV/COLMAP pinholes).  The science lives in :mod:`demtool.dem.local` (the local grid)
and :mod:`demtool.dem.sensors` (triangulation and the gap test).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.dem.params import DemParams
    from demtool.sensors.base import SensorModel
    from demtool.stagerun import StageRun

PathLike = str | os.PathLike | None


def run_dem_local(run: StageRun, params: DemParams, out, *, disparity_path, rectify_path,
                  rectification: dict, left: SensorModel, right: SensorModel,
                  up=None, mask_path: PathLike = None, error_path: PathLike = None,
                  points_out: PathLike = None) -> dict[str, Any]:
    """Triangulate every valid disparity in the models' frame and grid it locally.

    Writes OUT (heights in metres along ``up``, default the frame's +Z, on a local metric
    grid; no CRS, tag ``frame=map:local`` with the axes), ``--interpolated-mask``,
    ``--error-out`` (median ray gap per cell), ``--points-out`` (the kept points as PLY,
    LAS or LAZ by its suffix, the models' frame: :mod:`demtool.dem.point_cloud`) and the
    sidecar.  Returns the sidecar summary.
    """
    import numpy as np

    from demtool.dem.inputs import (
        geometry_from_rectification,
        read_disparity,
        rectifying_right_model,
    )
    from demtool.dem.local import (
        MATCH_RANGE_FACTOR,
        MIN_CONVERGENCE_PX,
        beyond_matches,
        check_up,
        check_upright,
        dem_on_local_grid,
        fit_ground_normal,
        footprint_gsd,
        infer_up,
        local_frame,
        weak_convergence,
    )
    from demtool.dem.sensors import screen_ray_gaps, triangulate_sensors
    from demtool.errors import ParameterError, ProcessingError
    from demtool.rectify.calibrated import rect_to_pixels, scene_distance

    log, prov = run.log, run.provenance
    if params.tile_size or params.scheduler or params.dry_run:
        raise ParameterError("--tile-size/--scheduler/--dry-run: the local-frame route "
                             f"({rectify_path}: models without a body) runs untiled")
    rectifying = rectifying_right_model(rectification, right, rectify_path)
    geometry = geometry_from_rectification(rectification, left, rectifying)
    disparity = read_disparity(disparity_path, rectify_path, rectification,
                               geometry.size_rect, log)
    if _sgm_filled(disparity.tags):
        log.warning("%s: sgm filled its occlusions from the background (sgm --fill, its "
                    "default): seen obliquely, the ground hidden behind rocks then gets "
                    "heights of the far ground (on the synthetic rover pair: RMSE 3.5 cm "
                    "instead of 1.0 cm); match local-frame pairs with sgm --no-fill",
                    disparity_path)
    d = disparity.data
    rows, cols = np.nonzero(np.isfinite(d))
    if rows.size < 3:
        raise ProcessingError(f"{disparity_path}: fewer than 3 valid disparities")
    x_left, y = cols.astype(np.float64), rows.astype(np.float64)
    x_right = x_left - d[rows, cols]
    l_line, l_sample = rect_to_pixels(left, geometry, "left", x_left, y, scene_distance(left))
    r_line, r_sample = rect_to_pixels(rectifying, geometry, "right", x_right, y,
                                      scene_distance(rectifying))
    tri = triangulate_sensors(left, right, l_line, l_sample, r_line, r_sample)
    finite = np.isfinite(tri.xyz).all(axis=1)
    in_front = finite & tri.in_front
    behind = int((finite & ~tri.in_front).sum())
    if not in_front.any():
        raise ProcessingError(f"{disparity_path}: no disparity triangulates in front of both "
                              "cameras")
    center = geometry.centers[0]
    centers = np.stack([left.camera_center(0.5 * left.lines),
                        right.camera_center(0.5 * right.lines)])
    far = in_front & beyond_matches(tri.xyz, center, _match_ranges(rectification, left,
                                                                   right, center))
    in_front &= ~far
    weak = in_front & weak_convergence(tri.xyz, centers, geometry.f_px)
    in_front &= ~weak
    if not in_front.any():
        raise ProcessingError(f"{disparity_path}: no disparity triangulates in front of both "
                              "cameras within the ranges of rectify's matches")
    if up is not None:
        up_source = "--up"
    else:
        up, up_source = infer_up(tri.xyz[in_front], centers)
        if "nearest frame axis" in up_source:
            log.warning("%s: up %s was %s: a frame tilted on a slope, or models whose "
                        "rotations are wrong (a .tsai's R transposed triangulates a tilted "
                        "mirror of the scene); give --up to have it checked",
                        rectify_path, ",".join(f"{v:.3g}" for v in up), up_source)
    check_up(up, tri.xyz[in_front], centers, "--up" if up_source == "--up" else up_source)
    check_upright(up, (left, right), rectify_path)
    frame = local_frame(up)
    if params.gsd is not None:
        gsd, gsd_source = float(params.gsd), "--gsd"
    else:
        gsd = footprint_gsd(tri.xyz[in_front], center, frame, 1.0 / geometry.f_px)
        gsd_source = "estimated (median pixel footprint on the plane normal to up)"
    keep, max_gap, median_gap = screen_ray_gaps(tri.gap, in_front, params.max_ray_gap, gsd)
    log.info("%d disparities: %d behind a camera (dropped), %d beyond %g times the ranges of "
             "rectify's matches (dropped), %d with rays converging by less than %g px "
             "(dropped), %d rays missing by more than %.3g m (dropped; median gap %.3g m); "
             "up %s (%s)", finite.size, behind, int(far.sum()), MATCH_RANGE_FACTOR,
             int(weak.sum()), MIN_CONVERGENCE_PX, int((in_front & ~keep).sum()), max_gap,
             median_gap,
             ",".join(f"{v:.3g}" for v in frame.up), up_source)
    result = dem_on_local_grid(tri.xyz[keep], tri.gap[keep], frame, gsd_m=gsd, left=left,
                               right=right, neighbours=params.outlier_neighbours,
                               threshold=params.outlier_threshold, median_px=params.median,
                               center=center)
    ranges = np.linalg.norm(tri.xyz[keep] - center, axis=1)
    normal, ground_rms = fit_ground_normal(tri.xyz[keep], centers)
    ground = float(np.median(tri.xyz[keep] @ normal))
    camera_above = float(centers.mean(axis=0) @ normal) - ground
    summary: dict[str, Any] = {
        "route": "disparity-local",
        "frame": "map:local",
        "up": [float(v) for v in frame.up],
        "up_source": up_source,
        "camera_above_fitted_ground_m": camera_above,
        "fitted_ground_tilt_deg": float(np.degrees(np.arccos(np.clip(abs(normal @ frame.up),
                                                                     0.0, 1.0)))),
        "fitted_ground_rms_m": ground_rms,
        "beyond_match_ranges": int(far.sum()),
        "weak_convergence": int(weak.sum()),
        "x_axis": [float(v) for v in frame.axes[0]],
        "shape": list(result.dem.shape),
        "gsd_m": gsd,
        "gsd_source": gsd_source,
        "valid_disparities": int(rows.size),
        "behind_camera": behind,
        "max_ray_gap_m": max_gap,
        "max_ray_gap_source": "--max-ray-gap" if params.max_ray_gap is not None else "default",
        "rejected_ray_gap": int((in_front & ~keep).sum()),
        "median_ray_gap_m": median_gap,
        "points": int(keep.sum()),
        "range_min_m": float(ranges.min()),
        "range_median_m": float(np.median(ranges)),
        "range_max_m": float(ranges.max()),
        "interpolated_fraction": float(result.filled.sum()
                                       / max(1, int(np.isfinite(result.dem).sum()))),
        **result.report,
    }
    log.info("local DEM %d×%d, GSD %.4g m (%s), %d cells measured, %d filled, heights "
             "%.4g … %.4g m along up (%.3g, %.3g, %.3g); ranges %.3g … %.3g m",
             result.dem.shape[1], result.dem.shape[0], gsd, gsd_source,
             result.report["measured_cells"], result.report["filled_cells"],
             summary["height_min_m"], summary["height_max_m"], *frame.up,
             summary["range_min_m"], summary["range_max_m"])
    tags = prov.tags(frame="map:local", dem_route="disparity-local", gsd_m=gsd,
                     units="metres along local_up", **frame.tags())
    from demtool.dem.output import write_dem_rasters

    with run.transaction():
        outputs = write_dem_rasters(run, params, out, result, transform=result.transform,
                                    crs=None, tags=tags, mask_path=mask_path,
                                    error_path=error_path,
                                    side_tags={"frame": "map:local", **frame.tags()})
        if points_out is not None:
            from demtool.dem.point_cloud import local_points, rectified_brightness
            from demtool.io.points import write_points

            brightness = rectified_brightness(rectify_path, rows, cols, log)
            write_points(points_out, **local_points(
                tri.xyz[keep], tri.gap[keep],
                None if brightness is None else brightness[keep],
                source=Path(rectify_path).name))
            outputs.append(Path(points_out))
        prov.write_sidecar(out, summary, outputs=outputs)
    return summary


def _match_ranges(rectification: dict, left, right, center):
    """Ranges (m) from ``center`` of rectify's inlier matches triangulated through the
    models (empty when the file has none)."""
    import numpy as np

    from demtool.dem.sensors import triangulate_sensors

    pl = np.asarray(rectification.get("points_left", np.zeros((0, 2))), dtype=np.float64)
    pr = np.asarray(rectification.get("points_right", np.zeros((0, 2))), dtype=np.float64)
    if len(pl) == 0 or pl.shape != pr.shape:
        return np.zeros(0)
    tri = triangulate_sensors(left, right, pl[:, 1] + 0.5, pl[:, 0] + 0.5, pr[:, 1] + 0.5,
                              pr[:, 0] + 0.5)
    ok = tri.in_front & np.isfinite(tri.xyz).all(axis=1)
    return np.linalg.norm(tri.xyz[ok] - center, axis=1)


def _sgm_filled(tags: dict) -> bool:
    """Whether sgm wrote this disparity with its occlusion fill on (its parameters tag)."""
    import json

    if tags.get("demtool_stage") != "sgm":
        return False
    try:
        return bool(json.loads(tags.get("demtool_params", "{}")).get("fill", False))
    except (ValueError, AttributeError):
        return False
