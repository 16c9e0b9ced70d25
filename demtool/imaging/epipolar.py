"""Robust epipolar geometry of point correspondences (split out of :mod:`demtool.imaging.features`).

* :func:`sampson_distance` — first-order geometric error of matches under F;
* :func:`ransac_fundamental` — F by USAC/MAGSAC (Barath et al. 2019/2020) or classic
  RANSAC through OpenCV, rejecting false matches;
* :func:`fit_fundamental` — the normalised 8-point algorithm (least squares on inliers).

:mod:`demtool.imaging.features` re-exports all of them, so ``features.ransac_fundamental`` and
friends keep working.  Point arrays are ``(N, 2)`` as ``(x, y)`` = ``(column, row)``.

References
----------
Hartley, R., Zisserman, A. (2004). Multiple View Geometry, 2nd ed. (Sampson
    distance, eq. 11.9; the fundamental matrix, ch. 9-11).
Hartley, R. (1997). In defense of the eight-point algorithm. IEEE TPAMI 19(6).
Barath, D., Noskova, J., Ivashechkin, M., Matas, J. (2020). MAGSAC++, a fast,
    reliable and accurate robust estimator. CVPR.
"""

from __future__ import annotations

import numpy as np

from demtool.errors import ParameterError, ProcessingError
from demtool.logs import get_logger

log = get_logger(__name__)


def sampson_distance(F: np.ndarray, points_a: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """First-order geometric error of correspondences under F, in pixels.

    Hartley & Zisserman (2004) eq. 11.9: with x_a, x_b homogeneous and the epipolar
    constraint ``x_b^T F x_a = 0``, the Sampson distance is
    ``|x_b^T F x_a| / sqrt((F x_a)_1^2 + (F x_a)_2^2 + (F^T x_b)_1^2 + (F^T x_b)_2^2)``.

    Parameters
    ----------
    F : (3, 3) float
        Fundamental matrix with ``x_b^T F x_a = 0``.
    points_a, points_b : (N, 2) float
        Corresponding pixel coordinates (x, y).

    Returns
    -------
    (N,) float64
        Distances in pixels.
    """
    a = np.column_stack([np.asarray(points_a, np.float64), np.ones(len(points_a))])
    b = np.column_stack([np.asarray(points_b, np.float64), np.ones(len(points_b))])
    Fa = a @ np.asarray(F, np.float64).T
    Ftb = b @ np.asarray(F, np.float64)
    numerator = np.abs(np.sum(b * Fa, axis=1))
    denominator = np.sqrt(Fa[:, 0] ** 2 + Fa[:, 1] ** 2 + Ftb[:, 0] ** 2 + Ftb[:, 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(denominator > 0, numerator / denominator, np.inf)


def ransac_fundamental(points_a: np.ndarray, points_b: np.ndarray, *, threshold_px: float = 1.0,
                       confidence: float = 0.999, method: str = "magsac", seed: int = 0,
                       max_iterations: int = 10000,
                       what: str = "the image pair") -> tuple[np.ndarray, np.ndarray]:
    """Fundamental matrix of point correspondences by a robust estimator.

    Parameters
    ----------
    points_a, points_b : (N, 2) float
        Matched pixel coordinates (x, y) in images a and b; N >= 8.
    threshold_px : float
        Inlier threshold in pixels: a match is an inlier when its Sampson distance
        (:func:`sampson_distance`) is at most this.
    confidence : float
        Desired probability (0 … 1, exclusive) that the estimate is outlier-free.
    method : {"magsac", "ransac"}
        ``cv2.USAC_MAGSAC`` (MAGSAC++, Barath et al. 2020) where this OpenCV has it,
        else (or for "ransac") classic ``cv2.FM_RANSAC``.
    seed : int
        Seed of OpenCV's random generator, so runs are reproducible.
    max_iterations : int
        Upper bound on the robust iterations.
    what : str
        Name of the pair, for error messages.

    Returns
    -------
    F : (3, 3) float64
        Rank-2 fundamental matrix with ``x_b^T F x_a = 0``, scaled to unit Frobenius norm.
    inliers : (N,) bool
        True for matches with Sampson distance <= ``threshold_px``.

    Raises
    ------
    ProcessingError
        Fewer than 8 matches or 8 inliers, coincident points (zero parallax: the
        same image twice), or no non-degenerate F.
    """
    import cv2

    if threshold_px <= 0:
        raise ParameterError(f"threshold_px must be > 0, got {threshold_px}")
    if not 0.0 < confidence < 1.0:
        raise ParameterError(f"confidence must be in (0, 1), got {confidence}")
    if method not in ("magsac", "ransac"):
        raise ParameterError(f"unknown RANSAC method {method!r}; should be one of magsac, ransac")
    a = np.asarray(points_a, np.float64).reshape(-1, 2)
    b = np.asarray(points_b, np.float64).reshape(-1, 2)
    if len(a) != len(b):
        raise ParameterError(f"point arrays differ in length: {len(a)} and {len(b)}")
    count = len(a)
    if count < 8:
        raise ProcessingError(f"{what}: only {count} matches, at least 8 are needed to "
                              "estimate a fundamental matrix")
    if np.median(np.linalg.norm(a - b, axis=1)) < 0.05:
        raise ProcessingError(f"{what}: the {count} matched points coincide (zero parallax; "
                              "are the two images identical?); the epipolar geometry is "
                              "undefined")
    flag = cv2.USAC_MAGSAC if (method == "magsac" and hasattr(cv2, "USAC_MAGSAC")) \
        else cv2.FM_RANSAC
    cv2.setRNGSeed(int(seed))
    try:
        F, _ = cv2.findFundamentalMat(a, b, flag, float(threshold_px), float(confidence),
                                      int(max_iterations))
    except cv2.error as exc:  # OpenCV raises on some degenerate inputs
        raise ProcessingError(f"{what}: fundamental-matrix estimation failed on {count} "
                              f"matches ({str(exc).strip().splitlines()[-1]})") from None
    if F is None or F.shape != (3, 3) or not np.all(np.isfinite(F)):
        raise ProcessingError(f"{what}: no fundamental matrix found from {count} matches "
                              "(degenerate configuration)")
    F = _enforce_rank2(F)
    inliers = sampson_distance(F, a, b) <= threshold_px
    n_inliers = int(inliers.sum())
    if n_inliers < 8:
        raise ProcessingError(f"{what}: only {n_inliers} of {count} matches agree with a "
                              "fundamental matrix; at least 8 are needed")
    log.debug("%s: F from %d matches, %d inliers (%s)", what, count, n_inliers, method)
    return F, inliers


def _enforce_rank2(F: np.ndarray) -> np.ndarray:
    """Closest rank-2 matrix in Frobenius norm, normalised to unit norm (H&Z sect. 11.1.1)."""
    U, s, Vt = np.linalg.svd(np.asarray(F, np.float64))
    if s[0] <= 0 or s[1] / s[0] < 1e-12:
        raise ProcessingError("degenerate fundamental matrix (rank < 2)")
    F2 = U @ np.diag([s[0], s[1], 0.0]) @ Vt
    return F2 / np.linalg.norm(F2)


def fit_fundamental(points_a: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Least-squares fundamental matrix of inlier matches (normalised 8-point algorithm).

    Hartley & Zisserman (2004), algorithm 11.1: Hartley normalisation of both point
    sets, linear solution by SVD, rank-2 enforcement, denormalisation.

    Parameters
    ----------
    points_a, points_b : (N, 2) float
        Inlier correspondences (x, y), N >= 8.

    Returns
    -------
    (3, 3) float64
        F with ``x_b^T F x_a = 0``, unit Frobenius norm.
    """
    a = np.asarray(points_a, np.float64).reshape(-1, 2)
    b = np.asarray(points_b, np.float64).reshape(-1, 2)
    if len(a) < 8 or len(a) != len(b):
        raise ProcessingError(f"the 8-point algorithm needs >= 8 matches, got {len(a)}")
    Ta, Tb = _normalising_transform(a), _normalising_transform(b)
    an = a @ Ta[:2, :2].T + Ta[:2, 2]
    bn = b @ Tb[:2, :2].T + Tb[:2, 2]
    design = np.column_stack([bn[:, 0] * an[:, 0], bn[:, 0] * an[:, 1], bn[:, 0],
                              bn[:, 1] * an[:, 0], bn[:, 1] * an[:, 1], bn[:, 1],
                              an[:, 0], an[:, 1], np.ones(len(a))])
    _, _, Vt = np.linalg.svd(design, full_matrices=False)
    Fn = _enforce_rank2(Vt[-1].reshape(3, 3))
    return _enforce_rank2(Tb.T @ Fn @ Ta)


def _normalising_transform(points: np.ndarray) -> np.ndarray:
    """Similarity moving the centroid to 0 and the mean distance to sqrt(2) (H&Z 4.4.4)."""
    centre = points.mean(axis=0)
    spread = np.mean(np.linalg.norm(points - centre, axis=1))
    scale = np.sqrt(2.0) / spread if spread > 0 else 1.0
    return np.array([[scale, 0.0, -scale * centre[0]],
                     [0.0, scale, -scale * centre[1]],
                     [0.0, 0.0, 1.0]])
