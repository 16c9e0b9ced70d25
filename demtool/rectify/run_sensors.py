"""Calibrated branch of ``demtool rectify``: rectification from two frame sensor models.

Called by :func:`demtool.rectify.run.run_rectify` when ``--sensor-left`` and
``--sensor-right`` are given.  Reads the images and the models, checks they belong
together, matches SIFT features, calls :func:`demtool.rectify.calibrated.rectify_sensors`
and writes left_rect.tif, right_rect.tif and a calibrated rectify.npz (the two models,
pointing correction applied, under ``sensor_left_*`` / ``sensor_right_*``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.rectify.output import LEFT_RECT, RECTIFY_NPZ, RIGHT_RECT, write_rectified_pair
from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.rectify.params import RectifyParams
    from demtool.sensors.base import SensorModel

RADII_RTOL = 1e-6


def read_frame_model(path: str | os.PathLike, image_path: str | os.PathLike,
                     image_shape: tuple[int, int], option: str) -> SensorModel:
    """Read a frame sensor model for an image and check it fits the image.

    A ``.tsai`` pinhole carries no image size: it takes the image's.  Raises InputError
    (one line naming the model file) for a line-scan or other non-frame model, or an
    image size that differs from the model's.
    """
    import dataclasses

    from demtool.errors import InputError
    from demtool.sensors import read_sensor
    from demtool.sensors.arrays import FRAME_TYPES, model_type

    p = Path(path)
    name = Path(image_path).stem if p.suffix.lower() == ".npz" else None
    model = read_sensor(p, name=name)
    kind = model_type(model)
    if kind == "linescan":
        raise InputError(f"{p}: is a line-scan model ({option}); rectify takes frame cameras "
                         "only: map-project a line-scan pair (`demtool mapproject`, then "
                         "`dem --mapprojected`) instead")
    if kind not in FRAME_TYPES:
        raise InputError(f"{p}: is a {kind} model ({option}); rectify takes frame cameras")
    if kind in ("tsai", "cahvor") and model.lines == 0 and model.samples == 0:
        # A .tsai file carries no image size: the image gives it.
        model = dataclasses.replace(model, height=int(image_shape[0]), width=int(image_shape[1]))
    if (model.lines, model.samples) != tuple(image_shape):
        raise InputError(f"{p}: the model is for a {model.samples} x {model.lines} px image "
                         f"but {image_path} is {image_shape[1]} x {image_shape[0]} px")
    return model


def check_same_body(left: SensorModel, right: SensorModel, left_path, right_path) -> None:
    """InputError when the two models are on different bodies (different radii)."""
    import numpy as np

    from demtool.errors import InputError

    a, b = left.radii, right.radii
    same = (a is None and b is None) or (
        a is not None and b is not None
        and np.allclose(np.asarray(a, float), np.asarray(b, float), rtol=RADII_RTOL))
    if not same:
        def text(r):
            return "no body" if r is None else " x ".join(f"{v:.6g}" for v in r) + " m"
        raise InputError(f"{right_path}: the model is on another body ({text(b)}) than "
                         f"{left_path} ({text(a)})")


def _homography_fit(map_x, map_y, step: int = 16):
    """3×3 homography original (x, y) → rectified (x, y), least squares on a lattice of the
    per-pixel maps (exact for an undistorted pinhole; an approximation otherwise)."""
    import cv2
    import numpy as np

    rows = np.arange(0, map_x.shape[0], step)
    cols = np.arange(0, map_x.shape[1], step)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    src = np.stack([map_x[rr, cc], map_y[rr, cc]], axis=-1).reshape(-1, 2)
    dst = np.stack([cc, rr], axis=-1).reshape(-1, 2).astype(np.float64)
    keep = np.isfinite(src).all(axis=1) & (np.abs(src) < 1e7).all(axis=1)
    if keep.sum() < 4:
        return np.eye(3)
    H, _ = cv2.findHomography(src[keep].astype(np.float64), dst[keep], 0)
    return H if H is not None else np.eye(3)


def rectify_with_sensors(left_path: str | os.PathLike, right_path: str | os.PathLike,
                         out_dir: str | os.PathLike, params: RectifyParams | None = None, *,
                         sensor_left: str | os.PathLike | None,
                         sensor_right: str | os.PathLike | None,
                         resolved: dict[str, Any] | None = None):
    """Calibrated rectification of LEFT and RIGHT with their sensor models into ``out_dir``.

    Returns
    -------
    demtool.rectify.calibrated.CalibratedRectification
    """
    import numpy as np

    from demtool import io as dio
    from demtool.errors import ParameterError, ProcessingError
    from demtool.imaging import features
    from demtool.imaging.checks import check_texture
    from demtool.rectify.calibrated import rectify_sensors, resampling_maps, warp
    from demtool.rectify.params import RectifyParams
    from demtool.sensors.arrays import model_to_arrays

    params = params or RectifyParams()
    run = StageRun("rectify", params, resolved=resolved,
                   inputs={"LEFT": left_path, "RIGHT": right_path,
                           "--sensor-left": sensor_left, "--sensor-right": sensor_right},
                   folders={"--out": out_dir},
                   outputs={"--out": [Path(out_dir) / n for n in (LEFT_RECT, RIGHT_RECT,
                                                                  RECTIFY_NPZ)],
                            "sidecar": sidecar_path(Path(out_dir) / RECTIFY_NPZ)})
    if sensor_left is None or sensor_right is None:
        missing = "--sensor-right" if sensor_left is not None else "--sensor-left"
        raise ParameterError(f"{missing} is needed too: give both sensor models or neither")
    if params.disparity_range is not None:
        raise ParameterError("--disparity-range is not used with sensor models")
    log = run.log
    for path in run.input_paths():
        dio.require_file(path, "input file")
    out = Path(out_dir)
    left_image = dio.read_image(left_path, what="left image")
    right_image = dio.read_image(right_path, what="right image")
    check_texture(left_image.data, left_path, what="left image")
    check_texture(right_image.data, right_path, what="right image")
    left_model = read_frame_model(sensor_left, left_path, left_image.data.shape,
                                  "--sensor-left")
    right_model = read_frame_model(sensor_right, right_path, right_image.data.shape,
                                   "--sensor-right")
    check_same_body(left_model, right_model, sensor_left, sensor_right)
    from demtool.rectify.checks import check_left_right

    check_left_right(left_model, right_model, sensor_left, sensor_right)
    from demtool.mapproject.checks import check_pair_overlaps

    check_pair_overlaps(left_model, right_model, sensor_left, sensor_right)
    left_name, right_name = Path(left_path).stem, Path(right_path).stem
    pair = f"{left_path} / {right_path}"
    left_features = features.detect_sift(left_image.data, max_features=params.max_features,
                                         contrast_threshold=params.contrast_threshold)
    right_features = features.detect_sift(right_image.data, max_features=params.max_features,
                                          contrast_threshold=params.contrast_threshold)
    pairs = features.match_descriptors(left_features.descriptors, right_features.descriptors,
                                       ratio=params.ratio, mutual=True)
    log.info("%s: %d and %d SIFT keypoints, %d matches (ratio %.2f, mutual)", pair,
             len(left_features), len(right_features), len(pairs), params.ratio)
    if len(pairs) < params.min_matches:
        raise ProcessingError(f"{pair}: only {len(pairs)} SIFT matches (ratio test "
                              f"{params.ratio}), at least {params.min_matches} are needed "
                              "(--min-matches); the images may not overlap or lack texture")
    result = rectify_sensors(
        left_model, right_model, left_features.points[pairs[:, 0]],
        right_features.points[pairs[:, 1]], systematic_px=params.systematic_residual,
        max_residual_px=params.max_vertical_residual,
        max_pointing_mrad=params.max_pointing_correction,
        disparity_margin=params.disparity_margin, min_matches=params.min_matches, what=pair)
    geometry, fit = result.geometry, result.fit
    rectifying = result.rectifying_right or result.right_model
    split = rectifying is not result.right_model  # rectified by a pose, triangulated as given
    maps = {side: resampling_maps(model, geometry, side)
            for side, model in (("left", left_model), ("right", rectifying))}
    left_rect = warp(left_image.data, *maps["left"])
    right_rect = warp(right_image.data, *maps["right"])
    for warped in (left_rect, right_rect):  # nodata is NaN, never ±inf (file contract)
        warped[np.isinf(warped)] = np.nan
    H_left = _homography_fit(*maps["left"])
    H_right = _homography_fit(*maps["right"])
    # rectified F = [e]x with e = (1, 0, 0): rows agree; F = H_rightᵀ F_rect H_left
    F = H_right.T @ np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]]) @ H_left
    from demtool.dem.sensors import triangulate_sensors

    pl, pr = result.points_left, result.points_right
    gaps = {}
    for label, model in (("spice", right_model), ("corrected", result.right_model)):
        tri = triangulate_sensors(left_model, model, pl[:, 1] + 0.5, pl[:, 0] + 0.5,
                                  pr[:, 1] + 0.5, pr[:, 0] + 0.5)
        gaps[label] = float(np.median(tri.gap))
    before = fit.residuals_before[fit.inliers]
    residuals = result.points_left_rect[:, 1] - result.points_right_rect[:, 1]
    rms_before = float(np.sqrt(np.mean(before ** 2)))
    rms = float(np.sqrt(np.mean(residuals ** 2)))
    omega_mrad = 1e3 * fit.omega_rect
    summary = {
        "left": left_name, "right": right_name, "calibrated": True,
        "sensor_left": str(sensor_left), "sensor_right": str(sensor_right),
        "matches": int(len(pairs)), "inliers": int(len(result.points_left)),
        "rms_vertical_residual_before_px": round(rms_before, 4),
        "median_vertical_residual_before_px": round(float(np.median(before)), 4),
        "rms_vertical_residual_px": round(rms, 4),
        "max_abs_vertical_residual_px": round(float(np.max(np.abs(residuals))), 4),
        "pointing_corrected": bool(result.corrected),
        "relative_pose": ("as given" if not result.corrected else "fitted to the matches' "
                          "rows for the rectification only; triangulation through the "
                          "models as given" if split else "corrected (rectification and "
                          "triangulation)"),
        "baseline_turn_mrad": [round(1e3 * float(v), 4)
                               for v in getattr(fit, "beta_rect", np.zeros(2))],
        "pointing_correction_mrad": [round(float(v), 4) for v in omega_mrad],
        "pointing_correction_angle_mrad": round(float(np.linalg.norm(omega_mrad)), 4),
        "median_ray_gap_spice_m": round(gaps["spice"], 3),
        "median_ray_gap_m": round(gaps["corrected"], 3),
        "focal_rect_px": round(float(geometry.f_px), 3),
        "disparity_range_px": [round(float(v), 3) for v in result.disparity_range],
        "disparity_infinity_px": round(float(geometry.cx_left - geometry.cx_right), 3),
        "size_left": [left_image.data.shape[1], left_image.data.shape[0]],
        "size_right": [right_image.data.shape[1], right_image.data.shape[0]],
        "size_rect": geometry.size_rect.tolist(),
    }
    log.info("%s: %d matches, %d agree with the models; vertical residual %.3f px RMS "
             "under the models (median %.3f px), %.3f px after rectification", pair,
             len(pairs), len(result.points_left), rms_before,
             summary["median_vertical_residual_before_px"], rms)
    log.info("median ray gap of the matches: %.3g m under the models as given, %.3g m "
             "through the models triangulating", gaps["spice"], gaps["corrected"])
    log.info("pointing correction of the right camera: %s (rectified x, y, z: %.3f, %.3f, "
             "%.3f mrad); disparity range %.1f … %.1f px; rectified canvas %d x %d",
             summary["relative_pose"] if result.corrected else "none needed", *omega_mrad,
             *result.disparity_range, *geometry.size_rect)
    arrays = {
        "H_left": H_left, "H_right": H_right, "F": F,
        "size_left": np.array(summary["size_left"]),
        "size_right": np.array(summary["size_right"]),
        "size_rect": geometry.size_rect,
        "points_left": result.points_left, "points_right": result.points_right,
        "points_left_rect": result.points_left_rect,
        "points_right_rect": result.points_right_rect,
        "disparity_range": result.disparity_range,
        # the disparity of a point at infinity: sgm never widens its range below it
        "disparity_infinity": np.asarray(geometry.cx_left - geometry.cx_right),
        "left_name": np.asarray(left_name), "right_name": np.asarray(right_name),
        "vertical_residuals": residuals,
        "rms_vertical_residual": np.asarray(rms),
        "n_matches": np.asarray(len(pairs)),
        "calibrated": np.asarray(True),
        "R_rect": geometry.R_rect,
        "K_left_rect": geometry.K("left"), "K_right_rect": geometry.K("right"),
        "pointing_correction": fit.rotation if result.corrected else np.eye(3),
        "pointing_correction_mrad": omega_mrad if result.corrected else np.zeros(3),
        **model_to_arrays(left_model, "sensor_left_"),
        **model_to_arrays(result.right_model, "sensor_right_"),
    }
    if split:  # dem resamples through the rectifying model, triangulates through the other
        arrays.update(model_to_arrays(rectifying, "rectifying_right_"))
    write_rectified_pair(run, out, (left_rect, right_rect), (left_name, right_name), arrays,
                         summary, ({"calibrated": True}, {"calibrated": True}))
    return result
