"""The relative pose of a calibrated local-frame pair, corrected from its matches.

A rig's calibration (a rover's mast pair, a lab rig) is often a few pixels off the
images it comes with: under the models, the SIFT matches' rectified rows disagree by
2-3 px.  Two causes leave different fingerprints in the rows:

* **a camera turned on its mount** (a relative rotation of a few mrad): the row
  residual is explained by a rotation ``ω`` of the right camera about its centre.  Then
  the corrected model is right for both the rectification and the triangulation.
* **an error the pose cannot express** (the lens or the intrinsics; the K10 pair of
  ASP's examples): no rotation explains the rows, and a pose that does (rotation plus
  a turn of the baseline) tilts the triangulated scene (K10: the ground 9° off level
  with it, 0.9° with the models as given).  Then the fitted pose only *rectifies*
  (rows agree, so a 1-D search along them finds the matches, as ASP's ±2 px search
  across rows does for this pair, ``corr-search -80 -2 20 2``), while the triangulation
  goes through the models as given: their disagreement with the images shows as the
  rays' gaps, reported beside the DEM.

:func:`fit_relative_pose` fits either, by robust least squares on the rows of the
rectified frame (x along the baseline): ``ω = (ω_x, ω_y, ω_z)`` turns the right camera
(ω_x shifts every row alike, ω_z tilts the rows with x, ω_y moves points along the rows
and shows in the rows only through perspective, ``Δy ≈ ω_y x y / f``), and
``β = (β_y, β_z)`` turns the baseline about the rectified y and z axes (the right
camera's centre moves on the sphere of the baseline's length about the left centre).
Rows of a rectified pair are epipolar lines: the rows of a match agree when the two
rays and the baseline are coplanar (Hartley & Zisserman 2004, *Multiple View
Geometry*, 2nd ed., sect. 9.6 and 11.12; Fusiello, Trucco & Verri 2000 for the
rectified frame).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from demtool.rectify.robust import ROBUST_NMADS, robust_inliers
from demtool.sensors.arrays import rotate_pointing, rotation_vector_matrix
from demtool.sensors.base import SensorModel


class RelativePoseFit(NamedTuple):
    """A correction of the right camera's pose fitted to the matches' rows.

    omega_rect : (3,) radians, rotation vector of the right camera, rectified frame
    beta_rect : (2,) radians, turn of the baseline about the rectified y and z axes
    rotation : (3, 3) the camera rotation in the models' frame (``d → rotation @ d``)
    baseline_rotation : (3, 3) the baseline's turn in the models' frame
    residuals_before, residuals_after : (N,) float64, rows y_left − y_right, pixels
    inliers : (N,) bool, matches kept by the robust fit
    """

    omega_rect: np.ndarray
    beta_rect: np.ndarray
    rotation: np.ndarray
    baseline_rotation: np.ndarray
    residuals_before: np.ndarray
    residuals_after: np.ndarray
    inliers: np.ndarray

    @property
    def rms_after(self) -> float:
        """RMS row residual of the inliers after the correction, pixels."""
        return float(np.sqrt(np.mean(self.residuals_after[self.inliers] ** 2)))

    @property
    def angle_mrad(self) -> float:
        """Size of the camera rotation, mrad."""
        return 1e3 * float(np.linalg.norm(self.omega_rect))


def _inliers(residuals: np.ndarray, floor_px: float) -> np.ndarray:
    """:func:`demtool.rectify.robust.robust_inliers`, NaN residuals outliers."""
    return robust_inliers(residuals, floor_px, skip_nan=True, nmads=ROBUST_NMADS)


def fit_relative_pose(left: SensorModel, right: SensorModel, R_rect: np.ndarray,
                      f_px: float, points_left: np.ndarray, points_right: np.ndarray, *,
                      baseline: bool, iterations: int = 4, floor_px: float = 1.0
                      ) -> RelativePoseFit:
    """Rotation of the right camera (and, with ``baseline``, a turn of the baseline) that
    best aligns the matches' rectified rows.

    Parameters
    ----------
    left, right : SensorModel
        Frame cameras of one frame.
    R_rect, f_px : the rectified frame of the models as given
        (:func:`demtool.rectify.calibrated.rectified_geometry`).
    points_left, points_right : (N, 2) float
        Matches (x, y) = (column, row), 0-based array coordinates.
    baseline : bool
        Also fit the baseline's direction (5 parameters instead of 3).
    iterations : int
        Robust refits (matches beyond max(``floor_px``, 4 NMAD) dropped each time).

    Returns
    -------
    RelativePoseFit
    """
    from scipy.optimize import least_squares

    pl = np.asarray(points_left, dtype=np.float64)
    pr = np.asarray(points_right, dtype=np.float64)
    d_left = left.image_to_ray(pl[:, 1] + 0.5, pl[:, 0] + 0.5).direction @ R_rect.T
    d_right = right.image_to_ray(pr[:, 1] + 0.5, pr[:, 0] + 0.5).direction @ R_rect.T
    count = 5 if baseline else 3

    def rows(p):
        turn = rotation_vector_matrix(p[:3])
        base = rotation_vector_matrix([0.0, p[3], p[4]]) if baseline else np.eye(3)
        dl = d_left @ base  # base.T @ d: the rectified frame turned with the baseline
        dr = d_right @ turn.T @ base
        with np.errstate(divide="ignore", invalid="ignore"):
            return f_px * (dl[:, 1] / dl[:, 2] - dr[:, 1] / dr[:, 2])

    before = rows(np.zeros(count))
    inliers = _inliers(before, max(floor_px, 2.0))
    p = np.zeros(count)
    for _ in range(iterations):
        if inliers.sum() < count + 3:
            break
        p = least_squares(lambda q, sel=inliers: rows(q)[sel], p, loss="huber",
                          f_scale=0.5, x_scale=1e-3).x
        inliers = _inliers(rows(p), floor_px)
    after = rows(p)
    omega = p[:3].copy()
    beta = p[3:5].copy() if baseline else np.zeros(2)
    rotation = R_rect.T @ rotation_vector_matrix(omega) @ R_rect
    baseline_rotation = R_rect.T @ rotation_vector_matrix([0.0, beta[0], beta[1]]) @ R_rect
    return RelativePoseFit(omega, beta, rotation, baseline_rotation, before, after, inliers)


def apply_relative_pose(left: SensorModel, right: SensorModel,
                        fit: RelativePoseFit) -> SensorModel:
    """The right model turned by ``fit.rotation`` about its centre and moved to the turned
    baseline (``C_left + baseline_rotation (C_right − C_left)``: its length kept)."""
    model = rotate_pointing(right, fit.rotation)
    if not np.any(fit.beta_rect):
        return model
    c_left = np.asarray(left.camera_center(0.5 * left.lines), dtype=np.float64)
    c_right = np.asarray(right.camera_center(0.5 * right.lines), dtype=np.float64)
    center = c_left + fit.baseline_rotation @ (c_right - c_left)
    if hasattr(model, "turned"):  # a CAHVOR camera
        return model.turned(np.eye(3), center)
    if not hasattr(model, "R") or not hasattr(model, "t"):
        raise ValueError(f"cannot move the centre of a {type(model).__name__} model")
    return dataclasses.replace(model, t=-model.R @ center)


#: rows that disagree by more than this (px RMS) under the models are not a calibration a
#: few pixels off: the images do not belong to these models (swapped, another rig)
MAX_CALIBRATION_ERROR_PX = 10.0

#: a rotation is applied when it lowers the rows' sum of squares by this many times
#: their variance after it (a 5σ improvement for one parameter; three are fitted)
SIGNIFICANT_CHI2 = 25.0


def significant(fit: RelativePoseFit, rms_before: float, systematic_px: float) -> bool:
    """Whether the rows call for the correction: they disagree by more than
    ``systematic_px`` RMS, or the fit lowers their sum of squares by more than
    :data:`SIGNIFICANT_CHI2` times their variance after it.

    A yaw of a few mrad moves the matches along the rows (a disparity bias of
    ``f ω_y`` pixels: the range off by a few per cent) and across them only through
    perspective (``ω_y x y / f``, a few tenths of a pixel at the corners): the RMS
    stays under a pixel, but over hundreds of matches the improvement is many σ.  The
    test keeps an exact rig's models untouched (its ω_y estimate is noise).
    """
    if rms_before > systematic_px:
        return True
    n = int(fit.inliers.sum())
    before = float(np.sum(fit.residuals_before[fit.inliers] ** 2))
    after = float(np.sum(fit.residuals_after[fit.inliers] ** 2))
    variance = max(after / max(n - 3, 1), 1e-6)
    return (before - after) / variance > SIGNIFICANT_CHI2


def better(pose: RelativePoseFit, turn: RelativePoseFit) -> bool:
    """Whether the pose (rotation and baseline turn) explains the rows significantly
    better than the rotation alone: the two extra parameters lower the sum of squares of
    the matches both keep by more than :data:`SIGNIFICANT_CHI2` times the pose's
    residual variance (then the error is not a camera turned on its mount)."""
    both = pose.inliers & turn.inliers
    n = int(both.sum())
    if n < 8:
        return False
    pose_ss = float(np.sum(pose.residuals_after[both] ** 2))
    turn_ss = float(np.sum(turn.residuals_after[both] ** 2))
    variance = max(pose_ss / (n - 5), 1e-6)
    return (turn_ss - pose_ss) / variance > SIGNIFICANT_CHI2


def correct_local_pose(left: SensorModel, right: SensorModel, R_rect: np.ndarray,
                       f_px: float, points_left: np.ndarray, points_right: np.ndarray,
                       rms_before: float, *, max_residual_px: float,
                       max_pointing_mrad: float, systematic_px: float, what: str
                       ) -> tuple[RelativePoseFit | None, SensorModel, SensorModel | None]:
    """Correct a local rig whose matches' rows disagree under its models (module docstring).

    Returns
    -------
    fit : RelativePoseFit or None
        The correction applied; None when no rotation improves the rows significantly
        (:func:`significant`) and they agree within ``systematic_px``: the models stay.
    triangulating : SensorModel
        The right model to triangulate with: turned by the rotation when a rotation
        explains the rows (to ``max_residual_px``, and a pose with the baseline turned too
        does not explain them significantly better, :func:`better`); else as given.
    rectifying : SensorModel or None
        In the second case, the pose (rotation and baseline turn) that rectifies the pair;
        None in the first (the triangulating model rectifies).

    Raises
    ------
    ProcessingError
        The rows disagree by more than :data:`MAX_CALIBRATION_ERROR_PX` under the models;
        a rotation explains the rows but is larger than ``max_pointing_mrad``; or no pose
        brings them within ``max_residual_px`` for half the matches.
    """
    from demtool.errors import ProcessingError
    from demtool.logs import get_logger

    log = get_logger(__name__)
    turn = fit_relative_pose(left, right, R_rect, f_px, points_left, points_right,
                             baseline=False)
    if not significant(turn, rms_before, systematic_px):
        return None, right, None
    pose = fit_relative_pose(left, right, R_rect, f_px, points_left, points_right,
                             baseline=True)
    if not better(pose, turn) and turn.rms_after <= max_residual_px \
            and turn.inliers.mean() >= 0.5:
        if turn.angle_mrad > max_pointing_mrad:
            raise ProcessingError(
                f"{what}: the models' relative pose is off: the SIFT matches' rows disagree "
                f"by {rms_before:.2f} px RMS under the models; a rotation of the right "
                f"camera by {turn.angle_mrad:.2f} mrad explains them ({turn.rms_after:.2f} "
                f"px after it), more than {max_pointing_mrad:g} mrad "
                "--max-pointing-correction; recalibrate the pair (a stereo calibration of "
                "the rig), or raise --max-pointing-correction (--max-vertical-residual "
                f"{max_residual_px:g} px) if that turn is plausible")
        log.info("%s: the right camera turned by %.3f mrad (rectified x %.3f, y %.3f, z %.3f "
                 "mrad) explains the matches' rows: %.3f -> %.3f px RMS; rectified and "
                 "triangulated with it", what, turn.angle_mrad, *(1e3 * turn.omega_rect),
                 rms_before, turn.rms_after)
        return turn, apply_relative_pose(left, right, turn), None
    if rms_before > MAX_CALIBRATION_ERROR_PX:
        raise ProcessingError(
            f"{what}: the SIFT matches' rows disagree by {rms_before:.1f} px RMS under the "
            f"models, more than a calibration's error ({MAX_CALIBRATION_ERROR_PX:g} px): "
            "the images do not belong to these models (left and right swapped, another "
            "rig's models?)")
    if pose.rms_after > max_residual_px or pose.inliers.mean() < 0.5:
        raise ProcessingError(
            f"{what}: the models' relative pose is off: the SIFT matches' rows disagree by "
            f"{rms_before:.2f} px RMS under the models, {turn.rms_after:.2f} px after the "
            f"best rotation of the right camera, {pose.rms_after:.2f} px after the best "
            f"pose ({100 * pose.inliers.mean():.0f} % of the matches agree; limit "
            f"{max_residual_px:g} px --max-vertical-residual); recalibrate the pair (a "
            "stereo calibration of the rig), raise --max-vertical-residual if that "
            "residual is acceptable, or rectify from the matches alone (no "
            "--sensor-left/--sensor-right)")
    log.warning("%s: the matches' rows disagree by %.2f px RMS under the models and no "
                "rotation of the right camera explains it (%.2f px after the best, %.2f "
                "mrad): the calibration is off elsewhere (lens, intrinsics). Rectified "
                "with the pose fitted to the rows (rotation %.2f mrad, baseline turned by "
                "%.2f mrad: %.3f px RMS); triangulated through the models as given, whose "
                "disagreement shows as the rays' gaps (dem --error-out)", what, rms_before,
                turn.rms_after, turn.angle_mrad, pose.angle_mrad,
                1e3 * float(np.linalg.norm(pose.beta_rect)), pose.rms_after)
    return pose, right, apply_relative_pose(left, right, pose)
