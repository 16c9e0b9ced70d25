"""Runner of ``demtool rectify``: uncalibrated rectification of a stereo pair."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.rectify.output import LEFT_RECT, RECTIFY_NPZ, RIGHT_RECT, write_rectified_pair
from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.rectify.params import RectifyParams


def _refuse_map_projected(left, right) -> None:
    """Two images on one map grid (orthoimages) are already aligned: no rectification.

    Raises
    ------
    InputError
        Both images carry the same CRS and pixel size (a map-projected pair).
    """
    from demtool.errors import InputError

    if left.crs is None or right.crs is None or left.crs != right.crs:
        return
    if not all(abs(a - b) <= 1e-6 * abs(a) for a, b in zip(left.spacing, right.spacing,
                                                          strict=True)):
        return
    raise InputError(f"{left.path}: {left.path.name} and {right.path.name} are already on "
                     "the same map grid (map-projected images): rectifying them would only "
                     "invent a transformation; match them directly (sgm/match) and "
                     "triangulate with `dem --mapprojected`")


CALIBRATED_ONLY = ("systematic_residual", "max_pointing_correction")


def run_rectify(left_path: str | os.PathLike, right_path: str | os.PathLike,
                out_dir: str | os.PathLike, params: RectifyParams | None = None, *,
                sensor_left: str | os.PathLike | None = None,
                sensor_right: str | os.PathLike | None = None,
                resolved: dict[str, Any] | None = None):
    """Rectify LEFT and RIGHT into ``out_dir``: left_rect.tif, right_rect.tif, rectify.npz.

    Reads both images, calls :func:`demtool.rectify.core.rectify_pair` (or, given both sensor
    models, :func:`demtool.rectify.run_sensors.rectify_with_sensors`), warps the images
    onto the common rectified canvas and writes everything (plus the sidecar
    ``rectify.npz.json``) in one output transaction.

    Returns
    -------
    demtool.rectify.core.Rectification, or the calibrated result
    """
    if sensor_left is not None or sensor_right is not None:
        from demtool.rectify.run_sensors import rectify_with_sensors

        return rectify_with_sensors(left_path, right_path, out_dir, params,
                                    sensor_left=sensor_left, sensor_right=sensor_right,
                                    resolved=resolved)
    import numpy as np

    from demtool import io as dio
    from demtool.imaging.checks import check_texture
    from demtool.rectify.core import rectify_pair, rotation_at_centre, warp_to_rectified
    from demtool.rectify.params import RectifyParams

    params = params or RectifyParams()
    run = StageRun("rectify", params, resolved=resolved,
                   inputs={"LEFT": left_path, "RIGHT": right_path}, folders={"--out": out_dir},
                   outputs={"--out": [Path(out_dir) / n for n in (LEFT_RECT, RIGHT_RECT,
                                                                  RECTIFY_NPZ)],
                            "sidecar": sidecar_path(Path(out_dir) / RECTIFY_NPZ)})
    log = run.log
    out = Path(out_dir)
    left_image = dio.read_image(left_path, what="left image")
    right_image = dio.read_image(right_path, what="right image")
    _refuse_map_projected(left_image, right_image)  # whatever their texture
    check_texture(left_image.data, left_path, what="left image")
    check_texture(right_image.data, right_path, what="right image")
    left_name, right_name = Path(left_path).stem, Path(right_path).stem
    pair = f"{left_path} / {right_path}"
    if left_image.data.shape != right_image.data.shape:
        log.info("%s: the images differ in size (%d x %d and %d x %d); that is fine", pair,
                 left_image.data.shape[1], left_image.data.shape[0],
                 right_image.data.shape[1], right_image.data.shape[0])
    core_params = {k: v for k, v in params.as_dict().items() if k not in CALIBRATED_ONLY}
    result = rectify_pair(left_image.data, right_image.data, **core_params, what=pair)
    left_rect = warp_to_rectified(left_image.data, result.H_left, result.size_rect)
    right_rect = warp_to_rectified(right_image.data, result.H_right, result.size_rect)
    for warped in (left_rect, right_rect):  # nodata is NaN, never ±inf (file contract)
        warped[np.isinf(warped)] = np.nan
    residuals = result.vertical_residuals
    summary = {
        "left": left_name,
        "right": right_name,
        "matches": result.n_matches,
        "ransac_inliers": result.n_ransac_inliers,
        "inliers": len(result.points_left),
        "outlier_iterations": result.iterations,
        "rms_vertical_residual_px": round(result.rms_vertical_residual, 4),
        "max_abs_vertical_residual_px": round(float(np.max(np.abs(residuals))), 4),
        "disparity_range_px": [round(float(v), 3) for v in result.disparity_range],
        "inlier_disparity_px": [round(float(result.disparities.min()), 3),
                                round(float(result.disparities.max()), 3)],
        "size_left": result.size_left.tolist(),
        "size_right": result.size_right.tolist(),
        "size_rect": result.size_rect.tolist(),
        # the turn each image takes (refused above MAX_ROTATION_DEG unless the parallax
        # shows it: demtool.rectify.checks.check_rotation)
        "turn_deg": [round(rotation_at_centre(result.H_left, result.size_left), 2),
                     round(rotation_at_centre(result.H_right, result.size_right), 2)],
    }
    log.info("%s: %d matches, %d RANSAC inliers, %d control points after %d outlier "
             "pass(es)", pair, result.n_matches, result.n_ransac_inliers,
             len(result.points_left), result.iterations)
    log.info("RMS vertical residual %.3f px (max %.3f px); disparity range %.1f … %.1f px "
             "(inliers %.1f … %.1f); rectified canvas %d x %d",
             result.rms_vertical_residual, summary["max_abs_vertical_residual_px"],
             *result.disparity_range, *summary["inlier_disparity_px"], *result.size_rect)
    arrays = {
        "H_left": result.H_left, "H_right": result.H_right, "F": result.F,
        "size_left": result.size_left, "size_right": result.size_right,
        "size_rect": result.size_rect,
        "points_left": result.points_left, "points_right": result.points_right,
        "points_left_rect": result.points_left_rect,
        "points_right_rect": result.points_right_rect,
        "disparity_range": result.disparity_range,
        "left_name": np.asarray(left_name), "right_name": np.asarray(right_name),
        "vertical_residuals": residuals,
        "rms_vertical_residual": np.asarray(result.rms_vertical_residual),
        "n_matches": np.asarray(result.n_matches),
        "n_ransac_inliers": np.asarray(result.n_ransac_inliers),
        "iterations": np.asarray(result.iterations),
    }
    write_rectified_pair(run, out, (left_rect, right_rect), (left_name, right_name), arrays,
                         summary, ({"homography": result.H_left.tolist()},
                                   {"homography": result.H_right.tolist()}))
    return result

