"""Calibrated epipolar rectification of a frame-camera pair from its sensor models.

The rectified pair shares one orientation ``R_rect`` (Fusiello, Trucco & Verri 2000,
"A compact algorithm for rectification of stereo pairs", Machine Vision and
Applications 12: new x axis along the baseline ``C_right − C_left``, new y axis
``z_old × x``, z axis ``x × y``, with ``z_old`` the left camera's boresight) and one
focal length ``f`` in pixels; each image has its own principal point, the right one
shifted so that the SIFT matches' median disparity is zero.  Rectified pixel (column x,
row y) of image *k* looks along ``R_rectᵀ ((x − cx_k)/f, (y − cy)/f, 1)`` from the
camera's centre; its source pixel is the model's ``ground_to_image`` of a point on that
ray, so lens distortion is undone by the per-pixel resampling maps (not a homography).

Rectified coordinates follow demtool's rectified rasters: pixel (row r, column c) is at
(x, y) = (c, r); disparity ``x_right = x_left − d``.  Sensor coordinates are CSM's
(line, sample), the first pixel's centre at (0.5, 0.5).

A systematic vertical residual of the SIFT matches (unadjusted SPICE: the two cameras'
relative pointing is off by a few mrad) is removed by a small rotation of the right
camera about its centre (:func:`fit_pointing_correction`), about the rectified x axis
(the baseline: a constant row offset) and z axis (a row offset growing with x).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from demtool.errors import ProcessingError
from demtool.logs import get_logger
from demtool.sensors.arrays import rotate_pointing, rotation_vector_matrix
from demtool.sensors.base import SensorModel

log = get_logger(__name__)


class RectifiedGeometry(NamedTuple):
    """The common rectified frame of a calibrated pair.

    R_rect : (3, 3) float64, body-fixed (world) → rectified camera frame (rows: x, y, z)
    f_px : float, focal length of the rectified cameras, pixels
    cx_left, cx_right, cy : float, principal points, rectified pixels
    size_rect : (2,) int, (width, height) of the common canvas
    centers : (2, 3) float64, camera centres (left, right), metres
    """

    R_rect: np.ndarray
    f_px: float
    cx_left: float
    cx_right: float
    cy: float
    size_rect: np.ndarray
    centers: np.ndarray

    def K(self, side: str) -> np.ndarray:
        """3×3 intrinsic matrix of the ``"left"`` or ``"right"`` rectified camera."""
        cx = self.cx_left if side == "left" else self.cx_right
        return np.array([[self.f_px, 0, cx], [0, self.f_px, self.cy], [0, 0, 1.0]])


def focal_px(model: SensorModel) -> float:
    """Focal length in pixels at the image centre: 1 / angle between the rays of the
    centre pixel and its neighbours (mean of the line and sample directions)."""
    line, sample = 0.5 * model.lines, 0.5 * model.samples
    rays = model.image_to_ray(np.array([line, line, line + 1.0]),
                              np.array([sample, sample + 1.0, sample])).direction
    angles = np.arccos(np.clip(rays[1:] @ rays[0], -1.0, 1.0))
    return float(1.0 / np.mean(angles))


def scene_distance(model: SensorModel) -> float:
    """Distance from the camera to the ground under the image centre (metres), or 1."""
    if model.radii is None:
        return 1.0
    line, sample = 0.5 * model.lines, 0.5 * model.samples
    ground = model.image_to_ground(line, sample)
    distance = float(np.linalg.norm(ground - model.camera_center(line)))
    return distance if np.isfinite(distance) and distance > 0 else 1.0


def rectifying_rotation(center_left, center_right, boresight_left) -> np.ndarray:
    """Fusiello et al. (2000) eq. (9)-(11): rows of the common rectified orientation.

    center_left, center_right : (3,) metres; boresight_left : (3,) unit look vector.
    Returns (3, 3): world → rectified camera (x along the baseline, z near the boresight).
    """
    x = np.asarray(center_right, float) - np.asarray(center_left, float)
    norm = np.linalg.norm(x)
    if not norm > 0:
        raise ProcessingError("the two cameras have the same centre: no stereo baseline")
    x /= norm
    y = np.cross(np.asarray(boresight_left, float), x)
    if np.linalg.norm(y) < 1e-6:
        raise ProcessingError("the baseline is along the left camera's boresight: the pair "
                              "cannot be rectified")
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    return np.stack([x, y, z])


def pixels_to_rect(model: SensorModel, R_rect: np.ndarray, f_px: float, line, sample
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Original CSM (line, sample) → rectified (x, y) with zero principal point."""
    direction = model.image_to_ray(line, sample).direction
    p = direction @ R_rect.T
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(p[..., 2] > 0, f_px * p[..., 0] / p[..., 2], np.nan)
        y = np.where(p[..., 2] > 0, f_px * p[..., 1] / p[..., 2], np.nan)
    return x, y


def rect_to_pixels(model: SensorModel, geometry: RectifiedGeometry, side: str, x, y,
                   distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Rectified (x, y) of the ``side`` image → original CSM (line, sample).

    The point at ``distance`` metres along the rectified ray is projected by the model's
    ``ground_to_image`` (a frame camera's image of a ray does not depend on it).
    """
    K = geometry.K(side)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    d = np.stack([(x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1], np.ones_like(x)], axis=-1)
    d = d @ geometry.R_rect  # R_rectᵀ d for each ray
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    center = geometry.centers[0 if side == "left" else 1]
    return model.ground_to_image(center + distance * d)


def _border(model: SensorModel, count: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """CSM (line, sample) of points along the image's outer edge."""
    h, w = model.lines, model.samples
    t = np.linspace(0.0, 1.0, count)
    lines = np.concatenate([np.zeros(count), t * h, np.full(count, float(h)), t * h])
    samples = np.concatenate([t * w, np.full(count, float(w)), t * w, np.zeros(count)])
    return lines, samples


def rectified_geometry(left: SensorModel, right: SensorModel, *,
                       disparity_offset: float = 0.0) -> RectifiedGeometry:
    """The common rectified frame and canvas of two frame models.

    Parameters
    ----------
    left, right : SensorModel
        Frame cameras in one body-fixed (world) frame.
    disparity_offset : float
        Pixels added to the right image's rectified x (its principal point moves by this
        much), e.g. the matches' median disparity so that disparities centre on zero.

    Returns
    -------
    RectifiedGeometry
        Canvas = union of both images' rectified footprints.
    """
    c_left = left.camera_center(0.5 * left.lines)
    c_right = right.camera_center(0.5 * right.lines)
    bore = left.image_to_ray(0.5 * left.lines, 0.5 * left.samples).direction
    R_rect = rectifying_rotation(c_left, c_right, bore)
    f = 0.5 * (focal_px(left) + focal_px(right))
    xs, ys = [], []
    for model, shift in ((left, 0.0), (right, disparity_offset)):
        x, y = pixels_to_rect(model, R_rect, f, *_border(model))
        if not np.isfinite(x).all():
            raise ProcessingError(f"image {model.name}: part of it looks away from the "
                                  "rectified frame (cameras too convergent to rectify)")
        xs.append(x + shift)
        ys.append(y)
    x_all, y_all = np.concatenate(xs), np.concatenate(ys)
    x0, y0 = np.floor(x_all.min()), np.floor(y_all.min())
    width = int(np.ceil(x_all.max() - x0)) + 1
    height = int(np.ceil(y_all.max() - y0)) + 1
    if width * height > 400e6:
        raise ProcessingError(f"the rectified canvas would be {width} x {height} px; the "
                              "cameras are too convergent for frame rectification")
    return RectifiedGeometry(R_rect=R_rect, f_px=f, cx_left=-x0,
                             cx_right=-x0 + disparity_offset, cy=-y0,
                             size_rect=np.array([width, height]),
                             centers=np.stack([c_left, c_right]))


def resampling_maps(model: SensorModel, geometry: RectifiedGeometry, side: str
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel maps (for ``cv2.remap``) of a rectified canvas into the original image.

    Returns
    -------
    map_x, map_y : (H_rect, W_rect) float32
        Original array column and row (0-based pixel centres: sample − 0.5, line − 0.5)
        of every rectified pixel; NaN where the ray misses the image's front side.
    """
    width, height = (int(v) for v in geometry.size_rect)
    distance = scene_distance(model)
    xx, yy = np.meshgrid(np.arange(width, dtype=np.float64),
                         np.arange(height, dtype=np.float64))
    line, sample = rect_to_pixels(model, geometry, side, xx, yy, distance)
    return (sample - 0.5).astype(np.float32), (line - 0.5).astype(np.float32)


def warp(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear resampling of ``image`` at the maps; NaN outside it (float32)."""
    import cv2

    data = np.asarray(image, dtype=np.float32)
    valid = np.isfinite(data)
    filled = np.where(valid, data, 0.0).astype(np.float32)
    mx = np.nan_to_num(map_x, nan=-1e6)
    my = np.nan_to_num(map_y, nan=-1e6)
    out = cv2.remap(filled, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=np.nan)
    weight = cv2.remap(valid.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    out[weight < 0.999] = np.nan
    return out


class PointingFit(NamedTuple):
    """Vertical residuals of matches before/after a pointing correction of the right camera.

    omega_rect : (3,) radians, rotation vector in the rectified frame (x, y, z); y is 0
    rotation : (3, 3) the correction in the body-fixed frame (``d → rotation @ d``)
    residuals_before, residuals_after : (N,) float64, rows y_left − y_right, pixels
    inliers : (N,) bool, matches kept by the robust fit
    """

    omega_rect: np.ndarray
    rotation: np.ndarray
    residuals_before: np.ndarray
    residuals_after: np.ndarray
    inliers: np.ndarray


def match_residuals(left: SensorModel, right: SensorModel, R_rect: np.ndarray, f_px: float,
                    points_left: np.ndarray, points_right: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rectified (x_left, y_left, x_right, y_right) of matches given as array (x, y)
    (0-based column, row), zero principal points."""
    pl = np.asarray(points_left, dtype=np.float64)
    pr = np.asarray(points_right, dtype=np.float64)
    xl, yl = pixels_to_rect(left, R_rect, f_px, pl[:, 1] + 0.5, pl[:, 0] + 0.5)
    xr, yr = pixels_to_rect(right, R_rect, f_px, pr[:, 1] + 0.5, pr[:, 0] + 0.5)
    return xl, yl, xr, yr


def _robust_inliers(residuals: np.ndarray, floor_px: float) -> np.ndarray:
    """:func:`demtool.rectify.robust.robust_inliers`, a NaN residual leaving no inlier."""
    from demtool.rectify.robust import robust_inliers

    return robust_inliers(residuals, floor_px, skip_nan=False)


def fit_pointing_correction(right: SensorModel, R_rect: np.ndarray, f_px: float,
                            points_right: np.ndarray, y_left: np.ndarray, *,
                            iterations: int = 3, floor_px: float = 2.0) -> PointingFit:
    """Rotation of the right camera (about its centre) that best aligns matched rows.

    Minimises the robust (Huber) sum of ``y_left − y_right(ω)`` over ω = (ω_x, 0, ω_z) in
    the rectified frame: ω_x about the baseline shifts every row alike, ω_z about the
    viewing axis tilts rows with x; ω_y only moves points along the rows (disparity) and is
    not observable from row residuals.  Outliers (|r − median| > max(floor, 4 NMAD)) are
    dropped and the fit repeated ``iterations`` times.

    Parameters
    ----------
    right : SensorModel
    R_rect, f_px : the rectified frame (:func:`rectified_geometry`)
    points_right : (N, 2) float, right matches (x, y) = (column, row), 0-based
    y_left : (N,) float, rectified rows of the left matches (zero principal point)

    Returns
    -------
    PointingFit
    """
    from scipy.optimize import least_squares

    pr = np.asarray(points_right, dtype=np.float64)
    d = right.image_to_ray(pr[:, 1] + 0.5, pr[:, 0] + 0.5).direction @ R_rect.T
    y_left = np.asarray(y_left, dtype=np.float64)

    def rows(omega2):
        rot = rotation_vector_matrix([omega2[0], 0.0, omega2[1]])
        p = d @ rot.T
        return f_px * p[:, 1] / p[:, 2]

    before = y_left - rows(np.zeros(2))
    inliers = _robust_inliers(before, floor_px)
    omega = np.zeros(2)
    for _ in range(iterations):
        if inliers.sum() < 3:
            break
        result = least_squares(lambda w, sel=inliers: y_left[sel] - rows(w)[sel], omega,
                               loss="huber", f_scale=0.5, x_scale=1e-3)
        omega = result.x
        after = y_left - rows(omega)
        inliers = _robust_inliers(after, floor_px)
    after = y_left - rows(omega)
    omega_rect = np.array([omega[0], 0.0, omega[1]])
    rotation = R_rect.T @ rotation_vector_matrix(omega_rect) @ R_rect
    return PointingFit(omega_rect, rotation, before, after, inliers)


class CalibratedRectification(NamedTuple):
    """Result of :func:`rectify_sensors`.

    geometry : RectifiedGeometry
    right_model : the right camera with the pointing correction applied (or as given)
    fit : PointingFit (residuals before/after; zero rotation when none was applied)
    corrected : bool, whether the correction was applied
    disparity_range : (2,) float, pixels, robust range of the inlier matches with margin
    points_left, points_right : (M, 2) inlier matches, original (x, y) 0-based
    points_left_rect, points_right_rect : (M, 2) the same on the canvas
    rectifying_right : the right model that rectified the pair: ``right_model``, or (a
        local rig whose error no rotation explains) the pose fitted to the matches' rows
        while ``right_model`` stays as given for the triangulation
        (:mod:`demtool.rectify.relative_pose`)
    """

    geometry: RectifiedGeometry
    right_model: SensorModel
    fit: PointingFit
    corrected: bool
    disparity_range: np.ndarray
    points_left: np.ndarray
    points_right: np.ndarray
    points_left_rect: np.ndarray
    points_right_rect: np.ndarray
    rectifying_right: SensorModel | None = None


def rectify_sensors(left: SensorModel, right: SensorModel, points_left: np.ndarray,
                    points_right: np.ndarray, *, systematic_px: float = 0.5,
                    max_residual_px: float = 1.0, max_pointing_mrad: float = 10.0,
                    disparity_margin: float = 2.0, min_matches: int = 30,
                    what: str = "the pair") -> CalibratedRectification:
    """Rectify a frame pair from its models; correct the right camera's pointing when the
    matches' vertical residual is systematic.

    Parameters
    ----------
    left, right : SensorModel (frame cameras, one body-fixed frame)
    points_left, points_right : (N, 2) float, SIFT matches (x, y) = (column, row), 0-based
    systematic_px : float
        Robust RMS vertical residual (px) above which a pointing correction is fitted.
    max_residual_px : float
        Largest RMS vertical residual of the inliers accepted after the correction
        (``--max-vertical-residual``).
    max_pointing_mrad : float
        Largest correction accepted (mrad); more means the SPICE is off.
    disparity_margin : float
        Margin of the disparity range (see :func:`demtool.rectify.core.robust_disparity_range`).
    min_matches : int
        Fewest inlier matches.
    what : str
        Names the pair in messages.

    Raises
    ------
    ProcessingError
        Too few matches, or a residual too large / not systematic: one line saying the
        SPICE is off and pointing to ``bundle`` with the models as priors.
    """
    from demtool.rectify.core import robust_disparity_range

    geometry = rectified_geometry(left, right)
    R, f = geometry.R_rect, geometry.f_px
    xl, yl, xr, yr = match_residuals(left, right, R, f, points_left, points_right)
    finite = np.isfinite(xl) & np.isfinite(yl) & np.isfinite(xr) & np.isfinite(yr)
    if finite.sum() < min_matches:
        raise ProcessingError(f"{what}: only {int(finite.sum())} SIFT matches in front of "
                              f"both cameras, at least {min_matches} are needed "
                              "(--min-matches)")
    pl, pr = np.asarray(points_left)[finite], np.asarray(points_right)[finite]
    xl, yl, xr, yr = xl[finite], yl[finite], xr[finite], yr[finite]
    residual = yl - yr
    inliers = _robust_inliers(residual, 2.0)
    rms_before = float(np.sqrt(np.mean(residual[inliers] ** 2)))
    fit = PointingFit(np.zeros(3), np.eye(3), residual, residual, inliers)
    corrected = False
    right_model = right
    rectifying = None
    if left.radii is None:  # a local rig: its relative pose (demtool.rectify.relative_pose)
        from demtool.rectify.relative_pose import correct_local_pose

        local_fit, right_model, rectifying = correct_local_pose(
            left, right, R, f, pl, pr, rms_before, max_residual_px=max_residual_px,
            max_pointing_mrad=max_pointing_mrad, systematic_px=systematic_px, what=what)
        corrected = local_fit is not None
        fit = local_fit if local_fit is not None else fit
        # a turned baseline turns the rectified frame too: every match is redone in it
        R = rectified_geometry(left, rectifying or right_model).R_rect
        xl, yl, xr, yr = match_residuals(left, rectifying or right_model, R, f, pl, pr)
        inliers = fit.inliers & np.isfinite(xl) & np.isfinite(xr)
    elif rms_before > systematic_px:
        fit = fit_pointing_correction(right, R, f, pr, yl)
        angle_mrad = 1e3 * float(np.linalg.norm(fit.omega_rect))
        rms_after = float(np.sqrt(np.mean(fit.residuals_after[fit.inliers] ** 2)))
        if (angle_mrad > max_pointing_mrad or rms_after > max_residual_px
                or fit.inliers.mean() < 0.5):
            measured = (f"the SIFT matches' rows disagree by {rms_before:.2f} px RMS under "
                        f"the models, {rms_after:.2f} px after the best pointing correction "
                        f"({angle_mrad:.2f} mrad, {100 * fit.inliers.mean():.0f} % inliers; "
                        f"limits {max_residual_px:g} px --max-vertical-residual, "
                        f"{max_pointing_mrad:g} mrad --max-pointing-correction)")
            raise ProcessingError(
                f"{what}: the SPICE is off: {measured}; run `demtool bundle --sensors` with "
                "these models as priors and rectify with the adjusted models (or raise "
                "--max-vertical-residual / --max-pointing-correction if that residual is "
                "acceptable)")
        right_model = rotate_pointing(right, fit.rotation)
        corrected = True
        xr, yr = pixels_to_rect(right_model, R, f, pr[:, 1] + 0.5, pr[:, 0] + 0.5)
        inliers = fit.inliers & np.isfinite(xr)
        log.info("%s: pointing correction of the right camera %.3f mrad (rectified x %.3f, "
                 "z %.3f mrad): vertical residual %.3f -> %.3f px RMS", what, angle_mrad,
                 1e3 * fit.omega_rect[0], 1e3 * fit.omega_rect[2], rms_before, rms_after)
    if inliers.sum() < min_matches:
        raise ProcessingError(f"{what}: only {int(inliers.sum())} matches agree with the "
                              f"models' geometry, at least {min_matches} are needed")
    offset = float(np.median((xl - xr)[inliers]))
    geometry = rectified_geometry(left, rectifying or right_model, disparity_offset=offset)
    shift_l = np.array([geometry.cx_left, geometry.cy])
    shift_r = np.array([geometry.cx_right, geometry.cy])
    pl_rect = np.stack([xl, yl], axis=-1)[inliers] + shift_l
    pr_rect = np.stack([xr, yr], axis=-1)[inliers] + shift_r
    disparities = pl_rect[:, 0] - pr_rect[:, 0]
    disparity_range = np.array(robust_disparity_range(disparities, margin=disparity_margin),
                               dtype=np.float64)
    # a point at infinity has d∞ = cx_left − cx_right (one orientation, one focal length),
    # every point in front of both cameras more: no search below it
    infinity = geometry.cx_left - geometry.cx_right
    disparity_range[0] = max(disparity_range[0], infinity - 1.0)
    disparity_range[1] = max(disparity_range[1], disparity_range[0])
    return CalibratedRectification(geometry, right_model, fit, corrected,
                                   np.asarray(disparity_range, dtype=np.float64),
                                   pl[inliers], pr[inliers], pl_rect, pr_rect,
                                   rectifying or right_model)
