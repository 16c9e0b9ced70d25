"""Checks that refuse a rectification the matches do not support (SIAM route).

* :func:`robust_disparity_range` — the dense matcher's search range from the control
  points, each end supported by several of them (issue 13's percentiles, issue 12's
  support rule).
* :func:`gric_difference` and ``_check_parallax`` — no parallax (identical images, a
  pure rotation, a flat scene): the epipolar geometry is undefined.
* :func:`rotation_at_centre`, :func:`epipolar_parallax`, :func:`check_rotation` — a
  rectification that turns the images more than a few degrees must be what the matches'
  parallax shows (a baseline along the columns), not F fitted to noise (already aligned
  images, e.g. two orthoimages on one map grid).

References
----------
Torr, P. H. S. (1998). Geometric motion segmentation and model selection. Phil. Trans.
    R. Soc. A 356, 1321-1340 (eq. 5: GRIC).
Hartley, R., Zisserman, A. (2004). Multiple View Geometry, 2nd ed., sect. 13.3
    (plane plus parallax).
"""

from __future__ import annotations

import numpy as np

from demtool.errors import ProcessingError
from demtool.imaging import features
from demtool.imaging.homography import apply_homography
from demtool.logs import get_logger

log = get_logger(__name__)

#: Fraction of the inlier disparity span added to each side of the disparity range.
DISPARITY_MARGIN_FRACTION = 0.1
#: Percentiles of the inlier disparities that bound the range (robust to a few gross
#: mismatches that lie on their epipolar line and so pass every geometric test).
DISPARITY_PERCENTILES = (1.0, 99.0)
#: A turn above ``max_rotation_deg`` (:func:`check_rotation`; the rectify default is
#: ``demtool.rectify.core.MAX_ROTATION_DEG``) needs this many times more RMS parallax along
#: the epipolar lines than across them ...
MIN_TURN_ANISOTROPY = 3.0
#: ... and, for images already on one grid (the matches' homography moves no corner by
#: more than ALIGNED_SHIFT_PX pixels), at least MIN_TURN_PARALLAX_PX of it, pixels.
ALIGNED_SHIFT_PX = 2.0
MIN_TURN_PARALLAX_PX = 1.0
#: Each end of the disparity range must be reached by at least this many control points.
MIN_RANGE_SUPPORT = 3
#: The GRIC test refuses a pair only if its RMS residual parallax (after the best
#: homography) is also below this many times the matching noise σ.
PARALLAX_NOISE_RATIO = 5.0

def robust_disparity_range(disparities: np.ndarray, *, margin: float = 2.0,
                           percentiles: tuple[float, float] = DISPARITY_PERCENTILES,
                           margin_fraction: float = DISPARITY_MARGIN_FRACTION,
                           min_support: int = MIN_RANGE_SUPPORT,
                           what: str = "the image pair") -> np.ndarray:
    """Search range of the dense matcher from the control points' disparities.

    The ``percentiles`` of the disparities, pulled in so that each end is reached by at
    least ``min_support`` control points, then widened on each side by the larger of
    ``margin`` pixels and ``margin_fraction`` of the span between them.  A gross
    mismatch that happens to lie on its epipolar line passes RANSAC and the
    vertical-residual loop; with the minimum and maximum it would widen the range
    arbitrarily (one match at 376 px where the rest lie in −10 … 30).  Percentiles
    alone do not stop it when there are few control points: with 40 of them the 99th
    percentile lies 39 % of the way from the second largest disparity to the largest,
    so one match still sets the range; the support rule (the ``min_support``-th
    smallest and largest disparities bound the range) does.  The control points
    left outside are logged, not refused: they are single matches, not evidence.

    Parameters
    ----------
    disparities : (N,) float
        ``x_left_rect − x_right_rect`` of the control points, pixels.
    min_support : int
        Least number of control points at or beyond each end of the range (before the
        margin); fewer than ``2 * min_support`` finite disparities is an error.

    Returns
    -------
    (2,) float64
        (min, max) disparity, pixels.

    Raises
    ------
    ProcessingError
        Too few finite disparities to support a range.
    """
    d = np.sort(np.asarray(disparities, np.float64).reshape(-1))
    d = d[np.isfinite(d)]
    min_support = max(1, int(min_support))
    if d.size == 0:
        raise ProcessingError("no control point disparity to set the disparity range from")
    if d.size < 2 * min_support:
        raise ProcessingError(
            f"{what}: only {d.size} control point disparities; each end of the disparity "
            f"range needs {min_support} to support it (give --disparity-range MIN MAX)")
    low, high = np.percentile(d, percentiles)
    low = max(float(low), float(d[min_support - 1]))
    high = min(float(high), float(d[-min_support]))
    outside = int(np.sum(d < low) + np.sum(d > high))
    if d[0] < low - margin or d[-1] > high + margin:
        log.info("%s: %d control points with disparities beyond %.1f … %.1f px (extremes "
                 "%.1f and %.1f px) left out of the range: each end needs %d matches",
                 what, outside, low, high, d[0], d[-1], min_support)
    pad = max(float(margin), margin_fraction * float(high - low))
    return np.array([low - pad, high + pad])



def gric_difference(F: np.ndarray, H: np.ndarray, points_left: np.ndarray,
                    points_right: np.ndarray) -> tuple[float, float]:
    """Torr's GRIC of the homography model minus that of the fundamental matrix.

    GRIC = Σ ρ(e_i² / σ²) + λ1 d n + λ2 k with ρ(x) = min(x, λ3 (r - d)), r = 4 (two
    2-D points), λ1 = ln r, λ2 = ln(r n), λ3 = 2; F: manifold dimension d = 3 with
    k = 7 parameters, H: d = 2, k = 8 (Torr 1998, "Geometric motion segmentation and
    model selection", Phil. Trans. R. Soc. A 356, eq. 5; Pollefeys et al. 2002 use it
    to detect degenerate views).  e_i is the Sampson distance for F and the
    symmetric transfer error / 2 for H (both approximate the distance in the 4-D
    joint image space); σ is estimated robustly from the F residuals.

    Returns
    -------
    difference : float
        GRIC(H) - GRIC(F): negative when the homography explains the matches at least
        as well, i.e. the pair has no usable parallax.
    sigma : float
        The noise estimate, pixels.
    """
    n = len(points_left)
    e_f = features.sampson_distance(F, points_left, points_right)
    sigma = max(1.4826 * float(np.median(e_f)), 1e-3)
    forward = apply_homography(H, points_left) - points_right
    backward = apply_homography(np.linalg.inv(H), points_right) - points_left
    e_h2 = (np.sum(forward**2, axis=1) + np.sum(backward**2, axis=1)) / 4.0
    e_h2 = np.where(np.isfinite(e_h2), e_h2, np.inf)
    r, lambda3 = 4.0, 2.0
    lambda1, lambda2 = np.log(r), np.log(r * n)
    gric_f = np.sum(np.minimum(e_f**2 / sigma**2, lambda3 * (r - 3))) + lambda1 * 3 * n \
        + lambda2 * 7
    gric_h = np.sum(np.minimum(e_h2 / sigma**2, lambda3 * (r - 2))) + lambda1 * 2 * n \
        + lambda2 * 8
    return float(gric_h - gric_f), sigma


def _check_parallax(F: np.ndarray, points_left: np.ndarray, points_right: np.ndarray,
                    threshold_px: float, what: str) -> None:
    """Refuse pairs whose matches one homography explains: F is then undetermined.

    Identical images, a pure rotation of the camera, or a flat scene seen from two
    places map one image onto the other by a homography; the epipolar geometry (and
    hence the rectification and the heights) is then not defined.  The homography is
    preferred by Torr's model-selection criterion (:func:`gric_difference`) when the
    residual parallax is below about 0.9 σ RMS.
    """
    import cv2

    H, _ = cv2.findHomography(points_left, points_right, cv2.RANSAC, threshold_px)
    if H is None or not np.all(np.isfinite(H)) or abs(np.linalg.det(H)) < 1e-12:
        return
    difference, sigma = gric_difference(F, H, points_left, points_right)
    transfer = np.linalg.norm(apply_homography(H, points_left) - points_right, axis=1)
    parallax = float(np.sqrt(np.nanmean(transfer**2)))
    beyond = int(np.sum(transfer > 3.0 * sigma))
    log.debug("%s: GRIC(H) - GRIC(F) = %.1f; RMS residual parallax %.3f px, noise σ %.3f px",
              what, difference, parallax, sigma)
    if difference <= 0 and parallax > PARALLAX_NOISE_RATIO * sigma:
        # GRIC caps each point's cost, so a dominant plane plus strong parallax elsewhere
        # can favour H; that parallax is what determines F
        log.info("%s: GRIC prefers a homography (GRIC(H) − GRIC(F) = %.1f), but the RMS "
                 "residual parallax %.2f px is %.0f× the matching noise %.2f px (%d of %d "
                 "matches beyond 3σ): kept", what, difference, parallax,
                 parallax / sigma, sigma, beyond, len(points_left))
        return
    if difference <= 0:
        raise ProcessingError(
            f"{what}: one homography explains the {len(points_left)} matches as well as a "
            f"fundamental matrix (GRIC(H) − GRIC(F) = {difference:.1f}; RMS residual "
            f"parallax {parallax:.2f} px for a matching noise σ of {sigma:.2f} px, "
            f"{beyond} matches beyond 3σ): no parallax (identical images, a pure rotation "
            "or a flat scene), so the epipolar geometry is undefined")


def rotation_at_centre(H: np.ndarray, size: np.ndarray) -> float:
    """Rotation the homography H applies at the centre of an image, degrees.

    The angle of the rotation part of the Jacobian J of x → H x (dehomogenised) at the
    image centre, taken from the similarity closest to J: ``atan2(J10 − J01, J00 + J11)``,
    counter-clockwise in the (x right, y down) pixel frame shown as usual, in (−180, 180].

    Parameters
    ----------
    H : (3, 3) float
        Homography from original to rectified pixel coordinates.
    size : (2,) int
        (width, height) of the image, pixels.
    """
    H = np.asarray(H, np.float64)
    centre = (np.asarray(size, np.float64).reshape(2) - 1.0) / 2.0
    w = float(centre @ H[2, :2] + H[2, 2])
    image = apply_homography(H, centre[None])[0]
    J = (H[:2, :2] - np.outer(image, H[2, :2])) / w
    return float(np.degrees(np.arctan2(J[1, 0] - J[0, 1], J[0, 0] + J[1, 1])))


def epipolar_parallax(F: np.ndarray, points_left: np.ndarray,
                      points_right: np.ndarray) -> tuple[float, float]:
    """RMS parallax of the matches along and across the epipolar lines, pixels.

    A homography (fitted by least squares to all matches, independently of F) takes out
    what the two views share — offset, rotation, scale, perspective of the mean scene
    plane; what remains is the parallax.  In a genuine stereo pair it runs along the
    epipolar lines through the right epipole (the plane-plus-parallax decomposition,
    H&Z sect. 13.3); when F is set by noise (already aligned images with no parallax to
    speak of) it has no preferred direction, or none of F's.

    Parameters
    ----------
    F : (3, 3) float
        Fundamental matrix, ``x_right^T F x_left = 0``.
    points_left, points_right : (N, 2) float
        Matches (x, y), pixels, N >= 4.

    Returns
    -------
    along, across : float
        RMS of the affine residuals projected on each match's epipolar line in the right
        image and on its normal, pixels.
    """
    import cv2

    pl = np.asarray(points_left, np.float64)
    pr = np.asarray(points_right, np.float64)
    H, _ = cv2.findHomography(pl, pr, 0)  # least squares over all matches
    if H is None or not np.all(np.isfinite(H)):
        return 0.0, 0.0
    residual = pr - apply_homography(H, pl)
    lines = np.column_stack([pl, np.ones(len(pl))]) @ np.asarray(F, np.float64).T
    direction = np.column_stack([lines[:, 1], -lines[:, 0]])
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-300)
    along = np.sum(residual * direction, axis=1)
    across = residual[:, 0] * -direction[:, 1] + residual[:, 1] * direction[:, 0]
    return float(np.sqrt(np.mean(along**2))), float(np.sqrt(np.mean(across**2)))


def alignment_shift(points_left: np.ndarray, points_right: np.ndarray,
                    size_left: np.ndarray) -> float:
    """How far the matches' least-squares homography moves the left image's corners, px.

    Near zero (a pixel or two) when the two images are already on one grid — two
    orthoimages of one map, or a pair co-registered by someone else.

    Parameters
    ----------
    points_left, points_right : (N, 2) float
        Matches (x, y), pixels, N >= 4.
    size_left : (2,) int
        (width, height) of the left image, pixels.
    """
    import cv2

    H, _ = cv2.findHomography(np.asarray(points_left, np.float64),
                              np.asarray(points_right, np.float64), 0)
    if H is None or not np.all(np.isfinite(H)):
        return float("inf")
    width, height = (float(v) - 1.0 for v in np.asarray(size_left).reshape(2))
    corners = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    return float(np.max(np.linalg.norm(apply_homography(H, corners) - corners, axis=1)))


def check_rotation(H_left: np.ndarray, H_right: np.ndarray, F: np.ndarray,
                   points_left: np.ndarray, points_right: np.ndarray, size_left: np.ndarray,
                   size_right: np.ndarray, *, max_rotation_deg: float,
                   what: str = "the image pair") -> float:
    """Refuse a rectification that turns an image by more than the matches justify.

    Hartley's rectification turns each image so that its epipolar lines become rows:
    by the angle of the epipole's direction, folded to ±90°.  A pair whose baseline
    runs along the image columns legitimately turns by ~90°; a pair of already aligned
    images (two orthoimages on one map grid, sub-pixel parallax) also turns by up to
    90° when F follows sub-pixel signals, and the rectification is then an artefact.
    The rule that tells them apart, for a turn larger than ``max_rotation_deg`` (either
    image, at its centre, :func:`rotation_at_centre`):

    1. the matches' parallax (:func:`epipolar_parallax`) must run along F's epipolar
       lines: RMS along them at least :data:`MIN_TURN_ANISOTROPY` times the RMS
       across — the epipole's direction is what the matches show, not F fitted to
       noise;
    2. images already on one grid (:func:`alignment_shift` below
       :data:`ALIGNED_SHIFT_PX`) must in addition show at least
       :data:`MIN_TURN_PARALLAX_PX` of RMS parallax along the epipolar lines: with
       sub-pixel parallax the pair belongs to the map-projected route.

    A raw pair with its baseline along the columns (the 192-px synthetic scene's
    view_00/view_03, B/H 0.5: turn −72°, parallax 0.79 px along and 0.22 px across, the
    matches' homography moving the corners by 28 px) passes; two aligned images with
    0.3 px of parallax along the columns (0.05 px across, corners moved < 0.1 px) are
    refused.

    Returns
    -------
    float
        The larger absolute turn of the two images, degrees.

    Raises
    ------
    ProcessingError
        A turn above ``max_rotation_deg`` that the parallax does not support.
    """
    turn_left = rotation_at_centre(H_left, size_left)
    turn_right = rotation_at_centre(H_right, size_right)
    turn = max(abs(turn_left), abs(turn_right))
    if turn <= max_rotation_deg:
        return turn
    along, across = epipolar_parallax(F, points_left, points_right)
    shift = alignment_shift(points_left, points_right, size_left)
    log.debug("%s: rectification turns the images by %.1f° and %.1f°; parallax %.2f px RMS "
              "along the epipolar lines, %.2f px across; the matches' homography moves the "
              "corners by up to %.1f px", what, turn_left, turn_right, along, across, shift)
    head = (f"{what}: the rectification would turn the images by {turn_left:.0f}° and "
            f"{turn_right:.0f}° (more than {max_rotation_deg:g}°), but ")
    if along < MIN_TURN_ANISOTROPY * across:
        raise ProcessingError(
            head + f"the matches' parallax does not show that baseline ({along:.2f} px RMS "
            f"along the epipolar lines, {across:.2f} px across; a turn needs "
            f"{MIN_TURN_ANISOTROPY:g}x): F follows noise; check that the images overlap "
            "and differ in viewpoint, or use the map-projected route (demtool mapproject, "
            "then dem --mapprojected)")
    if shift < ALIGNED_SHIFT_PX and along < MIN_TURN_PARALLAX_PX:
        raise ProcessingError(
            head + f"the images are already aligned (one homography moves them by at most "
            f"{shift:.2f} px) with only {along:.2f} px RMS of parallax along the epipolar "
            f"lines (a turn needs {MIN_TURN_PARALLAX_PX:g} px): orthoimages or one map "
            "grid; use the map-projected route (demtool mapproject, then dem "
            "--mapprojected)")
    log.info("%s: the rectification turns the images by %.0f° and %.0f°, as the matches' "
             "parallax (%.2f px RMS along the epipolar lines, %.2f px across) runs at that "
             "angle: the baseline is not along the rows", what, turn_left, turn_right,
             along, across)
    return turn


def check_left_right(left, right, left_path, right_path) -> None:
    """Refuse a pair whose right camera stands on the left of the left one.

    The baseline ``C_right − C_left`` must not point against the images' rows (their x
    axis, image right, in the models' frame): a side-by-side pair given the other way
    round (two ``.tsai`` swapped) would rectify turned by 180° and triangulate behind
    the cameras.  Pairs whose baseline runs across the rows (one camera above the other)
    pass: only a baseline within 60° of the images' left is refused.

    Raises
    ------
    InputError
        One line naming both model files.
    """
    from demtool.errors import InputError

    axes = []
    for model in (left, right):
        line, sample = 0.5 * model.lines, 0.5 * model.samples
        rays = model.image_to_ray(np.array([line, line]),
                                  np.array([sample - 0.5, sample + 0.5])).direction
        axis = rays[1] - rays[0]
        axes.append(axis / np.linalg.norm(axis))
    baseline = (np.asarray(right.camera_center(0.5 * right.lines), dtype=np.float64)
                - np.asarray(left.camera_center(0.5 * left.lines), dtype=np.float64))
    length = float(np.linalg.norm(baseline))
    if not length > 0:
        return
    along = float(baseline @ (axes[0] + axes[1])) / (2.0 * length)
    if along < -0.5:
        raise InputError(
            f"{right_path}: its camera stands {length * -along:.3g} m to the left of "
            f"{left_path}'s along the images' rows: the left and right models (or images) "
            "are swapped")
