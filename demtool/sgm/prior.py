"""Matching around a prior DEM: the disparity a DEM predicts for a calibrated pair, and the
right image warped by it, so that ``sgm`` searches only the residual.

This is the second pass of ASP's map-projected stereo (Beyer et al. 2018, "The Ames Stereo
Pipeline", Earth and Space Science 5, §2.3: correlate images projected onto a prior DEM and
add the residual back), done in the rectified frame so the search stays one-dimensional.
A window cost measures the disparity smoothed over its window (``G * d``); matching the
residual ``d − d_prior`` instead leaves ``(1 − G)(d − d_prior)`` unmeasured rather than
``(1 − G) d``, which is smaller where the prior holds the detail the window cannot — a DEM
fused from several pairs (``demtool fuse``), whose errors are partly independent of the
pair's own.

Frames: the rectified cameras of :class:`demtool.rectify.calibrated.RectifiedGeometry`
(rows of ``R_rect``: x, y, z; pixels ``x = f p_x / p_z + c_x``); points in the body-fixed
frame, metres; heights above the body's reference sphere.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

#: fixed-point iterations of the ray–DEM intersection and their stopping change, metres
MAX_ITERATIONS = 30
CONVERGED_M = 1e-3


#: rectified rows intersected at once (bounds the (rows, width, 3) float64 arrays)
ROWS_PER_BLOCK = 256


def rectified_rays(geometry, shape: tuple[int, int], first_row: int = 0) -> np.ndarray:
    """Unit body-fixed directions of the left rectified pixels' rays.

    Parameters
    ----------
    geometry : RectifiedGeometry
    shape : (rows, width) of the block of the rectified canvas
    first_row : int, the block's first row on the canvas

    Returns
    -------
    (rows, width, 3) float64
    """
    rows, cols = np.mgrid[first_row:first_row + shape[0], 0:shape[1]].astype(np.float64)
    K = geometry.K("left")
    direction = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1],
                          np.ones(shape)], axis=-1) @ geometry.R_rect  # R_rectᵀ d per pixel
    return direction / np.linalg.norm(direction, axis=-1, keepdims=True)


def intersect_dem(origin: np.ndarray, direction: np.ndarray, radius: float,
                  heights_at: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Where rays first meet a DEM, by fixed-point iteration on the height.

    Each ray is cut with the sphere of radius ``radius + h``; ``h`` is then the DEM's height
    below that point, until it changes by less than 1 mm (the usual ray–DEM iteration of
    ISIS ``DemShape::intersectSurface`` and ASP; it converges where the ray is steeper
    than the terrain, as for any view short of grazing).

    Parameters
    ----------
    origin : (3,) float64, body-fixed, metres
        The camera centre.
    direction : (..., 3) float64, unit body-fixed directions
    radius : float, metres
        The body's reference sphere.
    heights_at : callable
        (N, 3) body-fixed points → (N,) heights above the sphere, metres (NaN off the DEM).

    Returns
    -------
    (..., 3) float64, body-fixed metres; NaN where the ray misses the sphere or the DEM.
    """
    from demtool.sensors.base import ray_ellipsoid_intersection

    flat = direction.reshape(-1, 3)
    height = np.zeros(len(flat))
    points = np.full(flat.shape, np.nan)
    active = np.ones(len(flat), dtype=bool)
    for _ in range(MAX_ITERATIONS):
        points[active], hit = ray_ellipsoid_intersection(
            origin, flat[active], radius, radius, height[active], return_hit=True)
        new = heights_at(points[active])
        change = np.abs(new - height[active])
        bad = ~np.isfinite(new) | ~hit
        height[active] = np.where(bad, np.nan, new)
        points[np.flatnonzero(active)[bad]] = np.nan
        still = ~bad & (change > CONVERGED_M)
        active[np.flatnonzero(active)[~still]] = False
        if not active.any():
            break
    points[active] = np.nan  # not converged (a grazing ray on a steep slope): no answer
    return points.reshape(direction.shape)


def prior_disparity(geometry, shape: tuple[int, int], radius: float,
                    heights_at: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """The disparity a DEM predicts on the left rectified canvas.

    Each left rectified pixel's ray meets the DEM (:func:`intersect_dem`); the point is
    projected into the right rectified camera: ``d = x_left − x_right``.

    Parameters
    ----------
    geometry : RectifiedGeometry
        Of the calibrated pair (``centers``: left, right).
    shape : (height, width)
    radius : float, metres
    heights_at : callable, see :func:`intersect_dem`

    Returns
    -------
    (height, width) float64 disparity, pixels (``x_right = x_left − d``); NaN off the DEM.
    """
    out = np.full(shape, np.nan)
    x_left = np.arange(shape[1], dtype=np.float64)[None, :]
    for start in range(0, shape[0], ROWS_PER_BLOCK):
        stop = min(start + ROWS_PER_BLOCK, shape[0])
        rays = rectified_rays(geometry, (stop - start, shape[1]), start)
        points = intersect_dem(geometry.centers[0], rays, radius, heights_at)
        in_right = (points - geometry.centers[1]) @ geometry.R_rect.T
        with np.errstate(invalid="ignore", divide="ignore"):
            x_right = geometry.f_px * in_right[..., 0] / in_right[..., 2] + geometry.cx_right
            out[start:stop] = np.where(in_right[..., 2] > 0, x_left - x_right, np.nan)
    return out


def extend_nearest(values: np.ndarray, where: np.ndarray) -> np.ndarray:
    """``values`` with its NaN cells inside ``where`` set to the nearest finite value (so a
    prior that stops short of the image still centres the residual search there)."""
    from scipy.ndimage import distance_transform_edt

    known = np.isfinite(values)
    if not known.any():
        return values
    _, (rows, cols) = distance_transform_edt(~known, return_indices=True)
    return np.where(where & ~known, values[rows, cols], values)


def warp_right(right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """The right rectified image resampled at ``x − disparity`` (bicubic, OpenCV remap):
    where the prior is right, it lies on the left image and the residual is zero.

    The image is extended by its nearest values before the cubic resampling and the
    result masked where the sample falls outside it (nearest), so the warp does not eat
    a rim of pixels along the image's edge.

    Parameters
    ----------
    right : (H, W) float image, NaN outside the warped image
    disparity : (H, W) float64 pixels, NaN = no prior (the output is NaN there)

    Returns
    -------
    (H, W) float32
    """
    import cv2

    rows, cols = np.mgrid[0:right.shape[0], 0:right.shape[1]].astype(np.float32)
    map_x = np.where(np.isfinite(disparity), cols - disparity, -1e6).astype(np.float32)
    inside = np.isfinite(right)
    filled = extend_nearest(right.astype(np.float32), np.ones(right.shape, dtype=bool))
    warped = cv2.remap(filled, map_x, rows, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    seen = cv2.remap(inside.astype(np.uint8), map_x, rows, cv2.INTER_NEAREST,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    warped[(seen == 0) | ~np.isfinite(disparity)] = np.nan
    return warped


#: fewest matches of the pair, on the prior, needed to check it (fewer: taken as given)
MIN_CHECK_MATCHES = 10


class PriorCheck(NamedTuple):
    """How a prior's predicted disparity agrees with the pair's own matches."""

    matches: int  # matches on the prior (finite prediction inside the canvas)
    offset_px: float  # median of (match disparity − predicted), pixels
    spread_px: float  # NMAD of the same, pixels
    within: float  # share of the matches within ± search of the prediction + offset


def prior_against_matches(predicted: np.ndarray, points_left_rect: np.ndarray,
                          points_right_rect: np.ndarray, search_px: float) -> PriorCheck:
    """Compare a prior's disparity with the pair's matches, before it steers the search.

    Parameters
    ----------
    predicted : (H, W) float, pixels, NaN = none
        :func:`prior_disparity` on the left rectified canvas.
    points_left_rect, points_right_rect : (N, 2) float, rectified pixels (x, y)
        The pair's inlier matches (``rectify.npz``); their disparity is ``x_left −
        x_right`` at the left point.
    search_px : float
        The residual searched on each side of the prior.

    Returns
    -------
    PriorCheck
        ``offset_px`` is what the prior gets wrong on the whole (a DEM 30 m high is a
        constant offset), ``spread_px`` what it gets wrong point by point (an image given
        as the prior, a DEM of elsewhere).
    """
    left = np.asarray(points_left_rect, dtype=np.float64).reshape(-1, 2)
    right = np.asarray(points_right_rect, dtype=np.float64).reshape(-1, 2)
    col, row = np.rint(left[:, 0]).astype(np.int64), np.rint(left[:, 1]).astype(np.int64)
    inside = (row >= 0) & (row < predicted.shape[0]) & (col >= 0) & (col < predicted.shape[1])
    residual = np.full(len(left), np.nan)
    residual[inside] = (left[inside, 0] - right[inside, 0]) - predicted[row[inside],
                                                                        col[inside]]
    residual = residual[np.isfinite(residual)]
    if residual.size == 0:
        return PriorCheck(0, float("nan"), float("nan"), float("nan"))
    offset = float(np.median(residual))
    spread = float(1.4826 * np.median(np.abs(residual - offset)))
    within = float(np.mean(np.abs(residual - offset) <= search_px))
    return PriorCheck(int(residual.size), offset, spread, within)
