"""DEM from a disparity map of a rectified pair (the SIAM route of the NavCam study).

Disparities live in the left rectified frame (``x_right = x_left − d``).  Each valid
pixel is mapped back to both original images with the inverse rectification
homographies; heights then come either from calibrated triangulation with known
cameras, or — the study's uncalibrated route — from a robust least-squares 3-D
projective transformation fitted between (x, y, d) and a reference DEM.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from demtool.errors import ProcessingError
from demtool.imaging.robust import nmad
from demtool.sensors.pinhole import PinholeCamera, triangulate_midpoint


@dataclass(frozen=True)
class Correspondences:
    """Disparity samples mapped to both original images.

    Attributes
    ----------
    rectified : (N, 3) float64
        (x, y, d): left rectified pixel and disparity.
    left, right : (N, 2) float64
        The matching pixels (x, y) in the original left and right images.
    """

    rectified: np.ndarray
    left: np.ndarray
    right: np.ndarray


def apply_homography(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 2) points (x, y) through a 3 × 3 homography; NaN where w = 0."""
    pts = np.asarray(points, dtype=np.float64)
    homogeneous = np.column_stack([pts, np.ones(len(pts))]) @ np.asarray(H, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return homogeneous[:, :2] / homogeneous[:, 2:3]


def disparity_correspondences(disparity: np.ndarray, H_left: np.ndarray,
                              H_right: np.ndarray) -> Correspondences:
    """Map every valid disparity to a pair of original-image pixels.

    Parameters
    ----------
    disparity : (H, W) float
        Disparity in the left rectified frame, pixels, ``x_right = x_left − d``; NaN =
        invalid.
    H_left, H_right : (3, 3) float
        Rectification homographies (original → rectified) of ``rectify.npz``.

    Returns
    -------
    Correspondences

    Raises
    ------
    ProcessingError
        If the disparity has no valid pixel.
    """
    valid = np.isfinite(disparity)
    if not valid.any():
        raise ProcessingError("the disparity map has no valid pixel")
    rows, cols = np.nonzero(valid)
    d = disparity[rows, cols].astype(np.float64)
    x, y = cols.astype(np.float64), rows.astype(np.float64)
    left = apply_homography(np.linalg.inv(H_left), np.column_stack([x, y]))
    right = apply_homography(np.linalg.inv(H_right), np.column_stack([x - d, y]))
    return Correspondences(rectified=np.column_stack([x, y, d]), left=left, right=right)


def triangulate(correspondences: Correspondences, left_camera: PinholeCamera,
                right_camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """Calibrated route: triangulate the correspondences with the two known cameras.

    Returns
    -------
    points : (N, 3) float64
        World points (midpoint triangulation), metres.
    ray_distance : (N,) float64
        Shortest distance between the two rays, metres (match inconsistency).
    """
    points, ray_distance = triangulate_midpoint(left_camera, right_camera,
                                                correspondences.left, correspondences.right,
                                                return_distance=True)
    return points, ray_distance


class Screened(NamedTuple):
    """Triangulated points kept by :func:`screen_triangulation`.

    keep : (N,) bool; behind : points behind either camera; rejected_gap : points in
    front whose rays miss by more than ``max_gap`` (metres)
    """

    keep: np.ndarray
    behind: int
    rejected_gap: int
    max_gap: float


def screen_triangulation(points: np.ndarray, ray_gap: np.ndarray, left_camera: PinholeCamera,
                         right_camera: PinholeCamera, *,
                         max_ray_gap: float | None = None) -> Screened:
    """Cheirality and ray-gap test of triangulated points (every triangulating route).

    A point is kept when it lies in front of both cameras (positive depth, Hartley &
    Zisserman 2003 §6.2.3) and its two rays miss each other by at most ``max_ray_gap``;
    the default is :func:`demtool.dem.sensors.default_max_ray_gap` with one pixel's
    footprint at the median depth as the GSD.

    points : (N, 3) world points, metres; ray_gap : (N,) metres
    """
    from demtool.dem.sensors import default_max_ray_gap

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    gap = np.asarray(ray_gap, dtype=np.float64).ravel()
    finite = np.isfinite(pts).all(axis=1)
    with np.errstate(invalid="ignore"):
        front = finite & (left_camera.depth(pts) > 0) & (right_camera.depth(pts) > 0)
    behind = int((finite & ~front).sum())
    if max_ray_gap is None:
        if front.any():
            depth = float(np.median(left_camera.depth(pts[front])))
            max_ray_gap = default_max_ray_gap(gap[front], depth / left_camera.focal_px)
        else:
            max_ray_gap = float("inf")
    with np.errstate(invalid="ignore"):
        keep = front & (gap <= max_ray_gap)
    return Screened(keep, behind, int((front & ~keep).sum()), float(max_ray_gap))


# --------------------------------------------------------------------------------------
# 3-D projective transformation (15 DOF), robust DLT
# --------------------------------------------------------------------------------------


def _normalisation(points: np.ndarray) -> np.ndarray:
    """Normalising transformation in 3-D: centroid to the origin, unit RMS per axis.

    Hartley's conditioning, per axis rather than isotropic because heights span far
    less than image coordinates.
    """
    centroid = points.mean(axis=0)
    spread = np.sqrt(np.mean((points - centroid) ** 2, axis=0))
    scale = 1.0 / np.maximum(spread, 1e-12 * max(float(spread.max()), 1e-300))
    T = np.diag([*scale, 1.0])
    T[:3, 3] = -scale * centroid
    return T


def apply_projective_3d(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 3) points through a 4 × 4 projective transformation; NaN where w = 0."""
    pts = np.asarray(points, dtype=np.float64)
    homogeneous = np.column_stack([pts, np.ones(len(pts))]) @ np.asarray(T).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return homogeneous[:, :3] / homogeneous[:, 3:4]


def _dlt(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted DLT of ``target ~ T source`` on already normalised points (3 rows each)."""
    n = len(source)
    p = np.column_stack([source, np.ones(n)])
    zeros = np.zeros((n, 4))
    rows = []
    for axis in range(3):
        block = [zeros, zeros, zeros, -target[:, axis:axis + 1] * p]
        block[axis] = p
        rows.append(np.hstack(block))
    A = np.stack(rows, axis=1).reshape(3 * n, 16)
    if weights is not None:
        A = A * np.repeat(np.sqrt(weights), 3)[:, None]
    # Null vector of A: eigenvector of A^T A (16 x 16) with the smallest eigenvalue;
    # also correct for a minimal sample (15 equations), where A has more columns than rows.
    _, vectors = np.linalg.eigh(A.T @ A)
    return vectors[:, 0].reshape(4, 4)


@dataclass(frozen=True)
class ProjectiveFit:
    """A fitted 3-D projective transformation and its robust statistics.

    Attributes
    ----------
    T : (4, 4) float64
        ``target ~ T @ (source, 1)``, scaled so that ``T[3, 3] = 1`` when possible.
    inliers : (N,) bool
    residual_nmad : float
        NMAD of the inliers' residual in the third coordinate (height units).
    """

    T: np.ndarray
    inliers: np.ndarray
    residual_nmad: float


def fit_projective_3d(source: np.ndarray, target: np.ndarray, *, iterations: int = 300,
                      seed: int = 0, irls_iterations: int = 10,
                      sample_size: int = 2000) -> ProjectiveFit:
    """Robust least-squares 3-D projective transformation (15 DOF) ``target ~ T source``.

    Normalised DLT (Hartley & Zisserman 2004, §4.4 in 2-D, the same in 3-D);
    a least-median-of-squares search over minimal 5-point samples (Rousseeuw 1984)
    rejects gross outliers, then iteratively reweighted least squares with Tukey's
    biweight refines the transformation on all points.  Residuals are measured on
    the third coordinate (heights) and, for stability, on the first two.

    Parameters
    ----------
    source : (N, 3) float
        E.g. (x, y, disparity) of the rectified pair.
    target : (N, 3) float
        E.g. (x, y, reference height) in the target image.
    iterations : int
        Random minimal samples of the LMedS search.
    seed : int
    irls_iterations : int
    sample_size : int
        Points used to score each hypothesis (a random subset, for speed).

    Returns
    -------
    ProjectiveFit

    Raises
    ------
    ProcessingError
        Fewer than 5 correspondences, or a degenerate configuration.
    """
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    src, dst = src[finite], dst[finite]
    n = len(src)
    if n < 5:
        raise ProcessingError(f"a 3-D projective fit needs at least 5 points, got {n}")
    N_src, N_dst = _normalisation(src), _normalisation(dst)
    src_n = apply_projective_3d(N_src, src)
    dst_n = apply_projective_3d(N_dst, dst)
    rng = np.random.default_rng(seed)
    score_index = rng.choice(n, size=min(n, sample_size), replace=False)

    def residuals(T: np.ndarray, index: np.ndarray | slice) -> np.ndarray:
        mapped = apply_projective_3d(T, src_n[index])
        r = np.linalg.norm(mapped - dst_n[index], axis=1)
        return np.where(np.isfinite(r), r, np.inf)

    best_T, best_median = _dlt(src_n, dst_n), np.inf
    best_median = float(np.median(residuals(best_T, score_index) ** 2))
    for _ in range(iterations):
        sample = rng.choice(n, size=5, replace=False)
        try:
            T = _dlt(src_n[sample], dst_n[sample])
        except np.linalg.LinAlgError:
            continue
        median = float(np.median(residuals(T, score_index) ** 2))
        if median < best_median:
            best_T, best_median = T, median
    # Tukey-biweight IRLS from the LMedS estimate (Rousseeuw & Leroy 1987).
    T = best_T
    scale = 1.4826 * np.sqrt(best_median)
    for _ in range(irls_iterations):
        r = residuals(T, slice(None))
        scale = max(1.4826 * float(np.median(r[np.isfinite(r)])), 1e-12)
        c = 4.685 * scale
        weights = np.where(r < c, (1.0 - (r / c) ** 2) ** 2, 0.0)
        if np.count_nonzero(weights) < 5:
            break
        T = _dlt(src_n, dst_n, weights)
    T_full = np.linalg.inv(N_dst) @ T @ N_src
    if abs(T_full[3, 3]) > 1e-12 * np.abs(T_full).max():
        T_full = T_full / T_full[3, 3]
    r = residuals(T, slice(None))
    inliers = r < 4.685 * scale
    if inliers.sum() < 5:
        raise ProcessingError("the projective fit is degenerate (fewer than 5 inliers)")
    heights = apply_projective_3d(T_full, src[inliers])[:, 2]
    residual_nmad = nmad(heights - dst[inliers, 2])
    full_inliers = np.zeros(len(finite), dtype=bool)
    full_inliers[np.flatnonzero(finite)[inliers]] = True
    return ProjectiveFit(T=T_full, inliers=full_inliers, residual_nmad=residual_nmad)


def sample_bilinear(grid: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Bilinear samples of a grid at (N, 2) pixel positions (x, y); NaN outside or where a
    neighbour is NaN."""
    from scipy.ndimage import map_coordinates

    pts = np.asarray(pixels, dtype=np.float64)
    height, width = grid.shape
    values = map_coordinates(np.asarray(grid, dtype=np.float64), [pts[:, 1], pts[:, 0]],
                             order=1, mode="constant", cval=np.nan)
    outside = ((pts[:, 0] < 0) | (pts[:, 0] > width - 1) | (pts[:, 1] < 0)
               | (pts[:, 1] > height - 1) | ~np.isfinite(pts).all(axis=1))
    values[outside] = np.nan
    return values
