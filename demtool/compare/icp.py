"""Point-to-plane ICP between a DEM's points and a reference surface.

Frame: metric grid coordinates ``X = col · sx`` (right), ``Y = −row · sy`` (up),
``Z`` = height (up), right-handed.  The fitted similarity maps the DEM's points onto
the reference: ``p' = s R (p − c) + c + t`` with ``c`` the centroid of the DEM's
points, so ``t`` is the displacement of the centroid and the rotation is about it.

Method: point-to-plane ICP (Chen & Medioni 1992, Image Vis. Comput. 10(3)), with the
rotation linearised as in Low (2004, UNC TR04-004, eq. 7–10) and, optionally, an
isotropic scale (as in the point-to-surface alignment of the HiRISE comparison).
Each DEM point's correspondence is its vertical projection on the reference surface
(cubic interpolation), whose tangent plane there gives the normal; for a height
field this is the closest-point rule to first order and needs no k-d tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.compare.coreg import (
    MIN_PIXELS,
    _block_ids,
    _bootstrap_sigma,
    _solve,
)
from demtool.compare.grids import sample_bilinear, sample_cubic
from demtool.compare.shifts import gaussian_shift
from demtool.errors import ProcessingError
from demtool.imaging.robust import nmad
from demtool.logs import get_logger

__all__ = ["IcpResult", "apply_similarity", "icp_point_to_plane", "rotation_matrix"]

log = get_logger(__name__)


@dataclass(frozen=True)
class IcpResult:
    """A fitted similarity ``p' = scale · rotation (p − centre) + centre + translation_m``.

    Attributes
    ----------
    rotation : (3, 3) float64
        Rotation matrix in the grid frame (X right, Y up, Z up).
    centre : (3,) float64
        Centroid of the DEM's points, metres.
    scale : float
        Isotropic scale (1 when not estimated).
    translation_m : (3,) float64
        Displacement of the centroid, metres.
    rotation_deg : (3,) float64
        Rotation angles about X, Y, Z (right-handed, ``R = Rz Ry Rx``), degrees.
    sigma_rotation_deg, sigma_translation_m : (3,) float64
        One-sigma uncertainties (small-angle), degrees and metres.
    sigma_scale : float
        One-sigma uncertainty of the scale (0 when not estimated).
    rms_m : float
        RMS point-to-plane distance of the inliers after the fit, metres.
    iterations : int
    converged : bool
    count : int
        Points used in the last iteration.
    """

    rotation: np.ndarray
    centre: np.ndarray
    scale: float
    translation_m: np.ndarray
    rotation_deg: np.ndarray
    sigma_rotation_deg: np.ndarray
    sigma_translation_m: np.ndarray
    sigma_scale: float
    rms_m: float
    iterations: int
    converged: bool
    count: int

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) points (grid metres) to the reference frame."""
        return (self.scale * (points - self.centre) @ self.rotation.T + self.centre
                + self.translation_m)

    def as_dict(self) -> dict:
        """JSON-ready description."""
        return {
            "rotation_deg": self.rotation_deg.tolist(),
            "sigma_rotation_deg": self.sigma_rotation_deg.tolist(),
            "translation_m": self.translation_m.tolist(),
            "sigma_translation_m": self.sigma_translation_m.tolist(),
            "scale": self.scale,
            "sigma_scale": self.sigma_scale,
            "centre_m": self.centre.tolist(),
            "rotation_matrix": self.rotation.tolist(),
            "rms_m": self.rms_m,
            "iterations": self.iterations,
            "converged": self.converged,
            "count": self.count,
            "frame": "X = col*sx (right), Y = -row*sy (up), Z up; p' = s R (p - c) + c + t",
        }


def rotation_matrix(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis × angle, radians), Rodrigues' formula."""
    angle = float(np.linalg.norm(omega))
    if angle == 0.0:
        return np.eye(3)
    k = np.asarray(omega, dtype=np.float64) / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _euler_xyz_deg(rotation: np.ndarray) -> np.ndarray:
    """Angles (about X, Y, Z) of ``R = Rz(γ) Ry(β) Rx(α)``, degrees."""
    beta = np.arcsin(-np.clip(rotation[2, 0], -1.0, 1.0))
    alpha = np.arctan2(rotation[2, 1], rotation[2, 2])
    gamma = np.arctan2(rotation[1, 0], rotation[0, 0])
    return np.degrees([alpha, beta, gamma])


def _grid_points(dem: np.ndarray, usable: np.ndarray, spacing: tuple[float, float],
                 max_points: int) -> np.ndarray:
    stride = max(1, int(np.ceil(np.sqrt(usable.sum() / max_points))))
    sub = np.zeros(usable.shape, bool)
    sub[::stride, ::stride] = True
    rows, cols = np.nonzero(usable & sub)
    return np.column_stack([cols * spacing[0], -rows * spacing[1], dem[rows, cols]])


def icp_point_to_plane(dem: np.ndarray, reference: np.ndarray, *,
                       spacing: tuple[float, float] = (1.0, 1.0),
                       mask: np.ndarray | None = None, estimate_scale: bool = False,
                       max_iterations: int = 50, tolerance: float = 1e-6,
                       max_points: int = 200_000, smooth_sigma_px: float = 1.0,
                       initial_translation_m: np.ndarray | None = None,
                       seed: int = 0) -> IcpResult:
    """Rigid (or similarity) point-to-plane ICP of a DEM onto a reference surface.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid, on one grid
        DEM whose points are moved, and the reference surface.
    spacing : (float, float)
        Pixel size (x, y), metres.
    mask : (H, W) bool, optional
        True where DEM points may be used.
    estimate_scale : bool
        Also fit an isotropic scale about the centroid.
    max_iterations : int
    tolerance : float
        Convergence: largest displacement the last increment makes at the points'
        extent, as a fraction of the pixel spacing.
    max_points : int
        DEM points used (a regular subsample of the valid pixels).
    smooth_sigma_px : float
        Both surfaces are smoothed by the same Gaussian (pixels; 0 = none) first, so
        that interpolating the reference between its nodes is accurate (cubic
        interpolation of pixel-scale roughness would bias the fit) and noise is damped.
    initial_translation_m : (3,) float, optional
        Starting translation (X, Y, Z metres), e.g. a Nuth & Kääb shift.
    seed : int
        Seed of the block bootstrap.

    Returns
    -------
    IcpResult
        The transform taking the DEM's points onto the reference surface.

    Raises
    ------
    ProcessingError
        Fewer than 100 usable points, or the fit lost its correspondences.
    """
    if dem.shape != reference.shape:
        raise ValueError(f"dem and reference differ in shape: {dem.shape} vs {reference.shape}")
    sx, sy = float(spacing[0]), float(spacing[1])
    if smooth_sigma_px > 0:
        dem = gaussian_shift(dem, 0.0, 0.0, smooth_sigma_px)
        reference = gaussian_shift(reference, 0.0, 0.0, smooth_sigma_px)
    usable = np.isfinite(dem)
    if mask is not None:
        usable &= mask.astype(bool)
    points = _grid_points(dem, usable, (sx, sy), max_points)
    if points.shape[0] < MIN_PIXELS:
        raise ProcessingError(f"only {points.shape[0]} valid DEM points for ICP "
                              f"(need {MIN_PIXELS})")
    grad_row, grad_col = np.gradient(np.asarray(reference, dtype=np.float64))
    slope_x = grad_col / sx  # dZ/dX
    slope_y = -grad_row / sy  # dZ/dY (Y up = -row)
    centre = points.mean(axis=0)
    local = points - centre
    extent = float(np.abs(local).max()) + max(sx, sy)
    rotation = np.eye(3)
    scale = 1.0
    translation = np.zeros(3) if initial_translation_m is None else \
        np.asarray(initial_translation_m, dtype=np.float64).copy()
    converged = False
    iteration = 0
    for iteration in range(1, max_iterations + 1):  # noqa: B007 - used after the loop
        moved = scale * local @ rotation.T + centre + translation
        cols, rows = moved[:, 0] / sx, -moved[:, 1] / sy
        surface = sample_cubic(reference, rows, cols)
        zx = sample_bilinear(slope_x, rows, cols)
        zy = sample_bilinear(slope_y, rows, cols)
        valid = np.isfinite(surface) & np.isfinite(zx) & np.isfinite(zy)
        if valid.sum() < MIN_PIXELS:
            raise ProcessingError("ICP lost its correspondences (fewer than "
                                  f"{MIN_PIXELS} points over the reference)")
        norm = np.sqrt(1.0 + zx[valid] ** 2 + zy[valid] ** 2)
        normal = np.column_stack([-zx[valid], -zy[valid], np.ones(norm.size)]) / norm[:, None]
        arm = moved[valid] - centre  # the increment rotates about the centroid c
        distance = (moved[valid, 2] - surface[valid]) / norm
        columns = [np.cross(arm, normal), normal]
        if estimate_scale:
            columns.append(np.sum(normal * arm, axis=1)[:, None])
        design = np.column_stack(columns)
        residual = distance - np.median(distance)
        inliers = np.abs(residual) <= 4.0 * max(nmad(distance), 1e-12)
        if inliers.sum() < MIN_PIXELS:
            inliers = np.ones(distance.size, bool)
        increment, sigma, variance = _solve(design[inliers], -distance[inliers])
        if not np.all(np.isfinite(sigma)):
            raise ProcessingError("ICP is degenerate: the reference surface is too flat to "
                                  "constrain a rotation; use --align nuth-kaab or offset")
        omega, delta_t = increment[:3], increment[3:6]
        delta_s = 1.0 + (increment[6] if estimate_scale else 0.0)
        delta_r = rotation_matrix(omega)
        rotation = delta_r @ rotation
        scale *= delta_s
        translation = delta_s * delta_r @ translation + delta_t
        motion = (np.linalg.norm(omega) * extent + np.linalg.norm(delta_t)
                  + abs(delta_s - 1.0) * extent)
        if motion < tolerance * min(sx, sy):
            converged = True
            break
    rows_used = np.round(-points[valid][inliers][:, 1] / sy).astype(int)
    cols_used = np.round(points[valid][inliers][:, 0] / sx).astype(int)
    blocks = _block_ids(dem.shape)[rows_used, cols_used]
    boot = _bootstrap_sigma(design[inliers], -distance[inliers], blocks, seed=seed)
    sigma = np.fmax(sigma, boot)
    if not converged:
        log.warning("ICP did not converge in %d iterations", max_iterations)
    return IcpResult(
        rotation=rotation, centre=centre, scale=float(scale), translation_m=translation,
        rotation_deg=_euler_xyz_deg(rotation), sigma_rotation_deg=np.degrees(sigma[:3]),
        sigma_translation_m=sigma[3:6], sigma_scale=float(sigma[6]) if estimate_scale else 0.0,
        rms_m=float(np.sqrt(variance)), iterations=iteration, converged=converged,
        count=int(inliers.sum()))


def apply_similarity(dem: np.ndarray, transform: IcpResult, *,
                     spacing: tuple[float, float] = (1.0, 1.0),
                     max_iterations: int = 10, tolerance_px: float = 1e-4) -> np.ndarray:
    """Resample a DEM moved by an ICP transform onto its own grid.

    For each output pixel the source position whose transformed point lands on the
    pixel centre is found by fixed-point iteration (the horizontal Jacobian of a small
    rotation is nearly the identity), with cubic interpolation of the DEM.

    Parameters
    ----------
    dem : (H, W) float array, metres, NaN = invalid
    transform : IcpResult
    spacing : (float, float)
        Pixel size (x, y), metres.

    Returns
    -------
    (H, W) float64
        The moved DEM; NaN where no source point lands.
    """
    sx, sy = float(spacing[0]), float(spacing[1])
    rows, cols = np.indices(dem.shape, dtype=np.float64)
    target_x, target_y = cols * sx, -rows * sy
    x, y = target_x.copy(), target_y.copy()
    moved = np.full(dem.shape + (3,), np.nan)
    for _ in range(max_iterations):
        z = sample_cubic(dem, -y / sy, x / sx)
        moved = transform.apply(np.stack([x, y, z], axis=-1))
        error_x = target_x - moved[..., 0]
        error_y = target_y - moved[..., 1]
        x += np.nan_to_num(error_x)
        y += np.nan_to_num(error_y)
        worst = np.nanmax(np.abs(np.concatenate([(error_x / sx).ravel(),
                                                 (error_y / sy).ravel()])), initial=0.0)
        if worst < tolerance_px:
            break
    z = sample_cubic(dem, -y / sy, x / sx)
    moved = transform.apply(np.stack([x, y, z], axis=-1))
    return moved[..., 2]
