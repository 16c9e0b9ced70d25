"""Uncalibrated rectification of a stereo pair (the SIAM route of the NavCam study).

Pipeline (:func:`rectify_pair`): SIFT features on both images, Lowe's ratio test with
mutual nearest neighbours, a fundamental matrix by USAC/MAGSAC
(:mod:`demtool.imaging.features`), Hartley's projective rectification
(:func:`hartley_homographies`), then the study's outlier loop — drop the control
points whose rectified rows differ by more than ``max_vertical_residual`` pixels,
re-estimate F and the homographies, repeat until no point is dropped — and finally a
common shear (Loop & Zhang 1999) that keeps rectified pixels square, a uniform scale
that keeps the original resolution, and a translation that minimises the mean squared
distance between the rectified control points and puts both images on the smallest
common canvas.

Conventions
-----------
* ``H_left`` and ``H_right`` map original pixel coordinates (x, y, 1) to rectified
  ones (CONTRIBUTING.md); both rectified images share one canvas ``size_rect``
  (width, height).
* In the rectified frame corresponding points share a row, and the disparity is
  ``d = x_left - x_right`` (Middlebury's ``x_right = x_left - d``).  The translation
  makes the mean disparity of the control points zero, so ``d`` takes both signs; it
  increases toward the cameras when LEFT is the view whose camera lies on the left
  (−x side) of the rectified frame, and decreases otherwise.
* No mirror flip and at most a 90° rotation: the rotation that brings the epipole to
  the x axis is the smaller of the two candidates, and both homographies keep the
  orientation of the image (positive Jacobian determinant).  A turn of more than
  ``MAX_ROTATION_DEG`` (10°) is kept only when the matches' parallax runs along the
  epipolar lines (a baseline along the columns), and refused otherwise (already
  aligned images): :func:`demtool.rectify.checks.check_rotation`.

References
----------
Hartley, R. I. (1999). Theory and practice of projective rectification. IJCV 35(2),
    115-127 (sect. 5-6: the epipole-to-infinity map G R T, the matching transform).
Hartley, R., Zisserman, A. (2004). Multiple View Geometry, 2nd ed., sect. 11.12
    (algorithm 11.12.3) and result 13.6 (homographies compatible with F).
Loop, C., Zhang, Z. (1999). Computing rectifying homographies for stereo vision.
    CVPR (sect. 6: the shearing transform, eq. 17-18).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.errors import ParameterError, ProcessingError
from demtool.imaging import features
from demtool.imaging.homography import (  # noqa: F401  (re-exported for the dem stage)
    apply_homography,
    disparity_to_correspondences,
    original_to_rectified,
    rectified_to_original,
    warp_to_rectified,
)
from demtool.logs import get_logger
from demtool.rectify.checks import (  # noqa: F401  (public here since issue 13)
    ALIGNED_SHIFT_PX,
    DISPARITY_MARGIN_FRACTION,
    DISPARITY_PERCENTILES,
    MIN_RANGE_SUPPORT,
    MIN_TURN_ANISOTROPY,
    MIN_TURN_PARALLAX_PX,
    PARALLAX_NOISE_RATIO,
    _check_parallax,
    alignment_shift,
    check_rotation,
    epipolar_parallax,
    gric_difference,
    robust_disparity_range,
    rotation_at_centre,
)

log = get_logger(__name__)

#: A rectified canvas larger than this many times the two images' area is refused.
MAX_CANVAS_GROWTH = 4.0
#: A rectification that turns either image by more than this (degrees, at the image
#: centre) must be what the matches' parallax shows (:func:`check_rotation`).
MAX_ROTATION_DEG = 10.0


@dataclass(frozen=True)
class Rectification:
    """Result of :func:`rectify_pair` / :func:`rectify_matches`.

    Attributes
    ----------
    H_left, H_right : (3, 3) float64
        Homographies from original (x, y, 1) to rectified pixel coordinates.
    F : (3, 3) float64
        Fundamental matrix of the final inliers, ``x_right^T F x_left = 0``.
    size_left, size_right, size_rect : (2,) int64
        (width, height) of the original images and of the common rectified canvas.
    points_left, points_right : (N, 2) float64
        Inlier control points (x, y) in the original images.
    points_left_rect, points_right_rect : (N, 2) float64
        The same points in rectified coordinates.
    disparity_range : (2,) float64
        (min, max) search range, pixels: the 1st and 99th percentiles of
        ``x_left_rect - x_right_rect`` over the inliers widened by the margin
        (:func:`robust_disparity_range`), or the range the caller gave.
    rms_vertical_residual : float
        RMS of ``y_left_rect - y_right_rect`` over the inliers, pixels.
    n_matches : int
        Matches after the ratio test and mutual check.
    n_ransac_inliers : int
        Inliers of the robust F.
    iterations : int
        Passes of the vertical-residual outlier loop.
    """

    H_left: np.ndarray
    H_right: np.ndarray
    F: np.ndarray
    size_left: np.ndarray
    size_right: np.ndarray
    size_rect: np.ndarray
    points_left: np.ndarray
    points_right: np.ndarray
    points_left_rect: np.ndarray
    points_right_rect: np.ndarray
    disparity_range: np.ndarray
    rms_vertical_residual: float
    n_matches: int
    n_ransac_inliers: int
    iterations: int

    @property
    def vertical_residuals(self) -> np.ndarray:
        """(N,) float64: ``y_left_rect - y_right_rect`` of the inliers, pixels."""
        return self.points_left_rect[:, 1] - self.points_right_rect[:, 1]

    @property
    def disparities(self) -> np.ndarray:
        """(N,) float64: ``x_left_rect - x_right_rect`` of the inliers, pixels."""
        return self.points_left_rect[:, 0] - self.points_right_rect[:, 0]


def _translation(tx: float, ty: float) -> np.ndarray:
    return np.array([[1.0, 0.0, tx], [0.0, 1.0, ty], [0.0, 0.0, 1.0]])


def _corners(size: np.ndarray) -> np.ndarray:
    width, height = (float(s) for s in size)
    return np.array([[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]], float)


def _homogeneous_w(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ H[2, :2] + H[2, 2]


def _jacobian_det(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Determinant of the Jacobian of the mapping x → H x (dehomogenised) at points."""
    w = _homogeneous_w(H, points)
    return np.linalg.det(H) / w**3


# --------------------------------------------------------------------------------------
# Hartley rectification
# --------------------------------------------------------------------------------------


def epipoles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Epipoles of F (``F e_left = 0``, ``F^T e_right = 0``), homogeneous unit 3-vectors."""
    U, _, Vt = np.linalg.svd(np.asarray(F, np.float64))
    return Vt[2], U[:, 2]


def _epipole_to_infinity(epipole: np.ndarray, size: np.ndarray, what: str) -> np.ndarray:
    """Hartley's G R T: centre the image, rotate the epipole onto the x axis, send it to ∞.

    The rotation is the smaller of the two that put the epipole on the x axis (|angle|
    <= 90°), so the rectified image keeps roughly its original orientation.
    """
    centre = (np.asarray(size, float) - 1.0) / 2.0
    T = _translation(-centre[0], -centre[1])
    e = T @ epipole
    scale = max(float(np.max(size)), 1.0)
    at_infinity = abs(e[2]) * 1e8 <= np.hypot(e[0], e[1]) / scale
    direction = e[:2] if at_infinity else e[:2] / e[2]
    angle = np.arctan2(direction[1], direction[0])
    if angle > np.pi / 2:
        angle -= np.pi
    elif angle < -np.pi / 2:
        angle += np.pi
    c, s = np.cos(-angle), np.sin(-angle)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    G = np.eye(3)
    if not at_infinity:
        f = (R @ np.array([direction[0], direction[1], 1.0]))[0]
        half_diagonal = 0.5 * np.hypot(*size)
        if abs(f) <= half_diagonal:
            raise ProcessingError(
                f"{what}: the epipole lies inside or next to the image ({abs(f):.0f} px from "
                "its centre: forward motion along the view axis); projective rectification "
                "cannot handle this pair")
        G[2, 0] = -1.0 / f
    return G @ R @ T


def _compatible_homography(F: np.ndarray, e_right: np.ndarray, points_left: np.ndarray,
                           points_right: np.ndarray) -> np.ndarray:
    """Homography M = [e']_x F + e' v^T compatible with F that best maps left to right.

    H&Z result 13.6: every homography compatible with F has this form; v (3 unknowns)
    is solved by linear least squares from ``x_right × (M x_left) = 0`` in Hartley-
    normalised coordinates, so M is close to the homography of the mean scene plane
    and the left rectified image is as little distorted as possible.
    """
    Ta = features._normalising_transform(points_left)
    Tb = features._normalising_transform(points_right)
    Fn = np.linalg.inv(Tb).T @ F @ np.linalg.inv(Ta)
    en = Tb @ e_right
    en /= np.linalg.norm(en)
    ex = np.array([[0.0, -en[2], en[1]], [en[2], 0.0, -en[0]], [-en[1], en[0], 0.0]])
    A = ex @ Fn
    xa = np.column_stack([points_left @ Ta[:2, :2].T + Ta[:2, 2], np.ones(len(points_left))])
    xb = np.column_stack([points_right @ Tb[:2, :2].T + Tb[:2, 2], np.ones(len(points_right))])
    # (x_b × e') (x_a · v) = −x_b × (A x_a), three equations per match
    lhs_vec = np.cross(xb, en)  # (N, 3)
    rhs = -np.cross(xb, xa @ A.T)  # (N, 3)
    design = (lhs_vec[:, :, None] * xa[:, None, :]).reshape(-1, 3)
    v, *_ = np.linalg.lstsq(design, rhs.reshape(-1), rcond=None)
    Mn = A + np.outer(en, v)
    return np.linalg.inv(Tb) @ Mn @ Ta


def hartley_homographies(F: np.ndarray, points_left: np.ndarray, points_right: np.ndarray,
                         size_left: np.ndarray, size_right: np.ndarray, *,
                         what: str = "the image pair") -> tuple[np.ndarray, np.ndarray]:
    """Rectifying homographies of a pair from F and inlier matches (Hartley 1999).

    Parameters
    ----------
    F : (3, 3) float
        Fundamental matrix, ``x_right^T F x_left = 0``.
    points_left, points_right : (N, 2) float
        Inlier matches (x, y), N >= 8.
    size_left, size_right : (2,) int
        (width, height) of the images.

    Returns
    -------
    H_left, H_right : (3, 3) float64
        After which matches share a row.  ``H_right = G R T`` sends the right epipole
        to infinity along x; ``H_left = H_A H_r M`` with M a homography compatible with
        F and H_A the affine x-map minimising ``sum (x_left_rect - x_right_rect)^2``
        (Hartley 1999 sect. 6, H&Z algorithm 11.12.3).  Not yet sheared, scaled or
        translated onto the canvas (see :func:`rectify_matches`).
    """
    F = np.asarray(F, np.float64)
    pl = np.asarray(points_left, np.float64)
    pr = np.asarray(points_right, np.float64)
    _, e_right = epipoles(F)
    H_right = _epipole_to_infinity(e_right, size_right, what)
    M = _compatible_homography(F, e_right, pl, pr)
    H0 = H_right @ M
    left0 = apply_homography(H0, pl)
    right0 = apply_homography(H_right, pr)
    design = np.column_stack([left0, np.ones(len(pl))])
    (a, b, c), *_ = np.linalg.lstsq(design, right0[:, 0], rcond=None)
    H_A = np.array([[a, b, c], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    H_left = H_A @ H0
    for name, H, size in (("left", H_left, size_left), ("right", H_right, size_right)):
        w = _homogeneous_w(H, _corners(size))
        if np.any(w > 0) and np.any(w < 0):
            raise ProcessingError(f"{what}: the rectifying homography of the {name} image "
                                  "sends part of it to infinity (epipole too close to the "
                                  "image); projective rectification cannot handle this pair")
    H_left = H_left * np.sign(_homogeneous_w(H_left, _corners(size_left))[0])
    H_right = H_right * np.sign(_homogeneous_w(H_right, _corners(size_right))[0])
    return H_left, H_right


def loop_zhang_shear(H: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Shear S = [[sa, sb, 0], [0, 1, 0], [0, 0, 1]] restoring square pixels after H.

    Loop & Zhang (1999) sect. 6, eq. 17-18: the shear that makes the images of the
    two mid-lines of the image perpendicular again and keeps their length ratio
    (the aspect ratio).  It changes x only, so rows (the rectification) are kept.
    """
    # spans between the centres of the edge pixels (the paper writes w and h)
    width, height = (float(s) - 1.0 for s in size)
    a = (width / 2, 0.0)
    b = (width, height / 2)
    c = (width / 2, height)
    d = (0.0, height / 2)
    ha, hb, hc, hd = apply_homography(H, np.array([a, b, c, d]))
    xu, xv = hb - hd
    yu, yv = hc - ha
    denominator = height * width * (xv * yu - xu * yv)
    if abs(denominator) < 1e-12:
        return np.eye(3)
    sa = (height**2 * xv**2 + width**2 * yv**2) / denominator
    sb = (height**2 * xu * xv + width**2 * yu * yv) / -denominator
    if sa < 0:
        sa, sb = -sa, -sb
    return np.array([[sa, sb, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _canvas(H_left: np.ndarray, H_right: np.ndarray, size_left: np.ndarray,
            size_right: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Translate both homographies onto the smallest canvas that holds both images."""
    corners = np.vstack([apply_homography(H_left, _corners(size_left)),
                         apply_homography(H_right, _corners(size_right))])
    low = np.floor(corners.min(axis=0))
    high = np.ceil(corners.max(axis=0))
    size = (high - low + 1).astype(np.int64)
    area = float(size[0]) * float(size[1])
    original = float(np.prod(size_left)) + float(np.prod(size_right))
    if not np.all(np.isfinite(corners)) or area > MAX_CANVAS_GROWTH * original:
        raise ProcessingError(
            f"{what}: the rectified canvas would be {size[0]} x {size[1]} px, more than "
            f"{MAX_CANVAS_GROWTH:g} times the images' area (strong projective distortion: the "
            "epipole is close to the images)")
    T = _translation(-low[0], -low[1])
    return T @ H_left, T @ H_right, size


def _finish(F: np.ndarray, pl: np.ndarray, pr: np.ndarray, size_left: np.ndarray,
            size_right: np.ndarray, *, shear: bool, what: str) -> tuple[np.ndarray, ...]:
    """Hartley homographies + shear + resolution-preserving scale + MSD translation."""
    H_left, H_right = hartley_homographies(F, pl, pr, size_left, size_right, what=what)
    if shear:
        S_left = loop_zhang_shear(H_left, size_left)
        S_right = loop_zhang_shear(H_right, size_right)
        # one shear for both images keeps matched x-coordinates consistent
        S = 0.5 * (S_left + S_right)
        H_left, H_right = S @ H_left, S @ H_right
    # uniform scale: mean Jacobian determinant 1 over the control points (resolution kept)
    dets = np.concatenate([np.abs(_jacobian_det(H_left, pl)), np.abs(_jacobian_det(H_right, pr))])
    scale = 1.0 / np.sqrt(np.exp(np.mean(np.log(dets))))
    K = np.diag([scale, scale, 1.0])
    H_left, H_right = K @ H_left, K @ H_right
    # translation: zero mean disparity minimises the mean squared control-point distance
    offset = np.mean(apply_homography(H_left, pl)[:, 0] - apply_homography(H_right, pr)[:, 0])
    H_right = _translation(offset, 0.0) @ H_right
    H_left, H_right, size_rect = _canvas(H_left, H_right, size_left, size_right, what)
    return H_left, H_right, size_rect


def rectify_matches(points_left: np.ndarray, points_right: np.ndarray, size_left, size_right, *,
                    ransac_threshold: float = 1.0, max_vertical_residual: float = 1.0,
                    shear: bool = True, disparity_margin: float = 2.0, min_inliers: int = 8,
                    max_iterations: int = 20, seed: int = 0, n_matches: int | None = None,
                    disparity_range: tuple[float, float] | None = None,
                    max_rotation_deg: float = MAX_ROTATION_DEG,
                    what: str = "the image pair") -> Rectification:
    """Rectify a pair from its (putative) matches: robust F, Hartley, the outlier loop.

    Parameters
    ----------
    points_left, points_right : (N, 2) float
        Putative matches (x, y) in the original images (outliers allowed).
    size_left, size_right : (2,) int
        (width, height) of the images.
    ransac_threshold : float
        Sampson-distance inlier threshold of the robust F, pixels.
    max_vertical_residual : float
        The study's threshold: control points whose rectified rows differ by more are
        dropped and F and the homographies re-estimated, until none is dropped.
    shear : bool
        Apply the Loop–Zhang shear (square pixels, aspect ratio kept).
    disparity_margin : float
        Least number of pixels added on each side of the inliers' robust disparity
        range (their 1st and 99th percentiles); 10 % of its span when that is more
        (:func:`robust_disparity_range`).
    min_inliers : int
        Fewer final inliers is an error.
    max_iterations : int
        Bound on the outlier-loop passes.
    seed : int
        RANSAC seed.
    n_matches : int, optional
        Number of matches before this step (for the report); default N.
    disparity_range : (float, float), optional
        The (min, max) disparity to report instead of the one from the control points.
    max_rotation_deg : float
        A rectification turning either image by more is kept only if the matches'
        parallax supports it (:func:`check_rotation`).
    what : str
        Name of the pair for messages, e.g. ``"left.tif / right.tif"``.

    Returns
    -------
    Rectification

    Raises
    ------
    ProcessingError
        Too few matches or inliers, zero parallax (identical images, pure rotation,
        flat scene), epipole inside the image, a canvas that would explode, or a turn
        the parallax does not support.
    """
    if max_vertical_residual <= 0:
        raise ParameterError(f"max_vertical_residual must be > 0, got {max_vertical_residual}")
    if disparity_margin < 0:
        raise ParameterError(f"disparity_margin must be >= 0, got {disparity_margin}")
    if disparity_range is not None and not (
            np.all(np.isfinite(disparity_range)) and disparity_range[0] < disparity_range[1]):
        raise ParameterError(f"--disparity-range MIN MAX needs finite MIN < MAX, got "
                             f"{disparity_range[0]:g} {disparity_range[1]:g}")
    pl_all = np.asarray(points_left, np.float64).reshape(-1, 2)
    pr_all = np.asarray(points_right, np.float64).reshape(-1, 2)
    size_left = np.asarray(size_left, np.int64).reshape(2)
    size_right = np.asarray(size_right, np.int64).reshape(2)
    min_inliers = max(8, int(min_inliers))
    F, inliers = features.ransac_fundamental(pl_all, pr_all, threshold_px=ransac_threshold,
                                             seed=seed, what=what)
    n_ransac = int(inliers.sum())
    if n_ransac < min_inliers:
        raise ProcessingError(f"{what}: only {n_ransac} of {len(pl_all)} matches are "
                              f"RANSAC inliers; at least {min_inliers} are needed")
    pl, pr = pl_all[inliers], pr_all[inliers]
    _check_parallax(F, pl, pr, ransac_threshold, what)
    iterations = 0
    while True:
        iterations += 1
        H_left, H_right, size_rect = _finish(F, pl, pr, size_left, size_right, shear=shear,
                                             what=what)
        residual = apply_homography(H_left, pl)[:, 1] - apply_homography(H_right, pr)[:, 1]
        keep = np.abs(residual) <= max_vertical_residual
        log.debug("%s: outlier pass %d, %d control points, RMS vertical residual %.3f px, "
                  "%d dropped", what, iterations, len(pl), np.sqrt(np.mean(residual**2)),
                  int((~keep).sum()))
        if keep.all() or iterations >= max_iterations:
            break
        if keep.sum() < min_inliers:
            raise ProcessingError(f"{what}: only {int(keep.sum())} control points keep a "
                                  f"vertical residual <= {max_vertical_residual} px; at least "
                                  f"{min_inliers} are needed")
        pl, pr = pl[keep], pr[keep]
        F = features.fit_fundamental(pl, pr)
    check_rotation(H_left, H_right, F, pl, pr, size_left, size_right,
                   max_rotation_deg=max_rotation_deg, what=what)
    left_rect = apply_homography(H_left, pl)
    right_rect = apply_homography(H_right, pr)
    if disparity_range is None:
        disparity_range = robust_disparity_range(left_rect[:, 0] - right_rect[:, 0],
                                                 margin=disparity_margin, what=what)
    disparity_range = np.asarray(disparity_range, np.float64).reshape(2)
    rms = float(np.sqrt(np.mean((left_rect[:, 1] - right_rect[:, 1]) ** 2)))
    return Rectification(
        H_left=H_left, H_right=H_right, F=F, size_left=size_left, size_right=size_right,
        size_rect=size_rect, points_left=pl, points_right=pr, points_left_rect=left_rect,
        points_right_rect=right_rect, disparity_range=disparity_range,
        rms_vertical_residual=rms, n_matches=int(n_matches if n_matches is not None
                                                 else len(pl_all)),
        n_ransac_inliers=n_ransac, iterations=iterations)


def rectify_pair(left: np.ndarray, right: np.ndarray, *, min_matches: int = 30,
                 ratio: float = 0.8, ransac_threshold: float = 1.0,
                 max_vertical_residual: float = 1.0, shear: bool = True,
                 disparity_margin: float = 2.0, max_features: int = 0,
                 contrast_threshold: float = 0.04, seed: int = 0,
                 disparity_range: tuple[float, float] | None = None,
                 max_rotation_deg: float = MAX_ROTATION_DEG,
                 what: str = "the image pair") -> Rectification:
    """Uncalibrated rectification of two images (the SIAM route of the NavCam study).

    Parameters
    ----------
    left, right : (H, W) float
        Grey images (any DN range, NaN = nodata); they may differ in size.
    min_matches : int
        Fewer matches after the ratio test (or fewer final inliers) is an error.
    ratio : float
        Lowe's ratio-test threshold.
    max_features : int
        SIFT keypoints kept per image, the strongest first (0 = all).
    contrast_threshold : float
        SIFT contrast threshold.
    ransac_threshold, max_vertical_residual, shear, disparity_margin, seed,
    disparity_range, max_rotation_deg, what
        See :func:`rectify_matches`.

    Returns
    -------
    Rectification
    """
    if min_matches < 8:
        raise ParameterError(f"min_matches must be >= 8, got {min_matches}")
    left_features = features.detect_sift(left, max_features=max_features,
                                         contrast_threshold=contrast_threshold)
    right_features = features.detect_sift(right, max_features=max_features,
                                          contrast_threshold=contrast_threshold)
    pairs = features.match_descriptors(left_features.descriptors, right_features.descriptors,
                                       ratio=ratio, mutual=True)
    log.info("%s: %d and %d SIFT keypoints, %d matches (ratio %.2f, mutual)", what,
             len(left_features), len(right_features), len(pairs), ratio)
    if len(pairs) < min_matches:
        raise ProcessingError(f"{what}: only {len(pairs)} SIFT matches (ratio test {ratio}), "
                              f"at least {min_matches} are needed (--min-matches); the images "
                              "may not overlap or lack texture")
    size_left = np.array([left.shape[1], left.shape[0]])
    size_right = np.array([right.shape[1], right.shape[0]])
    return rectify_matches(left_features.points[pairs[:, 0]], right_features.points[pairs[:, 1]],
                           size_left, size_right, ransac_threshold=ransac_threshold,
                           max_vertical_residual=max_vertical_residual, shear=shear,
                           disparity_margin=disparity_margin, min_inliers=min_matches,
                           seed=seed, n_matches=len(pairs), disparity_range=disparity_range,
                           max_rotation_deg=max_rotation_deg, what=what)
