"""Homographies: mapping points between original and rectified frames, and warping.

Used by ``rectify`` (which makes the homographies) and by the stages that consume a
rectification (``dem`` maps disparities back to the original images).  Conventions as
in CONTRIBUTING.md: points are (x, y) = (column, row); ``H`` maps original pixel
coordinates (x, y, 1) to rectified ones; a disparity ``d`` of the left rectified
pixel (x, y) means the right rectified point (x - d, y).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from demtool.errors import ParameterError

# --------------------------------------------------------------------------------------
# Point mapping
# --------------------------------------------------------------------------------------


def apply_homography(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points through a homography.

    Parameters
    ----------
    H : (3, 3) float
    points : (N, 2) float
        Pixel coordinates (x, y).

    Returns
    -------
    (N, 2) float64
        Mapped coordinates; NaN where the point maps to infinity.
    """
    p = np.asarray(points, np.float64).reshape(-1, 2)
    mapped = p @ np.asarray(H, np.float64)[:, :2].T + np.asarray(H, np.float64)[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = mapped[:, :2] / mapped[:, 2:3]
    out[mapped[:, 2] == 0] = np.nan
    return out


def rectified_to_original(points_rect: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Map rectified (x, y) back to the original image with ``H^-1``, (N, 2) float64."""
    return apply_homography(np.linalg.inv(np.asarray(H, np.float64)), points_rect)


def original_to_rectified(points: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Map original (x, y) to rectified coordinates with ``H``, (N, 2) float64."""
    return apply_homography(H, points)


def disparity_to_correspondences(disparity: np.ndarray, H_left: np.ndarray,
                                 H_right: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Turn a disparity map of the left rectified image into original-image matches.

    The left rectified pixel (x, y) with disparity d matches the right rectified point
    (x - d, y); both are mapped back with the inverse homographies.

    Parameters
    ----------
    disparity : (H, W) float
        Disparity in the left rectified frame, pixels, NaN = invalid.
    H_left, H_right : (3, 3) float
        The rectifying homographies (original → rectified).

    Returns
    -------
    points_left, points_right : (N, 2) float64
        Matching points (x, y) in the original left and right images.
    pixels : (N, 2) int64
        (row, column) of each valid disparity pixel in the rectified grid.
    """
    d = np.asarray(disparity, np.float64)
    rows, cols = np.nonzero(np.isfinite(d))
    left_rect = np.column_stack([cols, rows]).astype(np.float64)
    right_rect = left_rect.copy()
    right_rect[:, 0] -= d[rows, cols]
    return (rectified_to_original(left_rect, H_left), rectified_to_original(right_rect, H_right),
            np.column_stack([rows, cols]).astype(np.int64))


# --------------------------------------------------------------------------------------
# Warping
# --------------------------------------------------------------------------------------


@njit(parallel=True, cache=True)
def _warp_bilinear(image: np.ndarray, H_inv: np.ndarray, height: int,
                   width: int) -> np.ndarray:  # pragma: no cover - compiled
    out = np.empty((height, width), np.float32)
    src_h, src_w = image.shape
    for row in prange(height):
        for col in range(width):
            w = H_inv[2, 0] * col + H_inv[2, 1] * row + H_inv[2, 2]
            x = (H_inv[0, 0] * col + H_inv[0, 1] * row + H_inv[0, 2]) / w
            y = (H_inv[1, 0] * col + H_inv[1, 1] * row + H_inv[1, 2]) / w
            if not (x >= 0.0 and y >= 0.0 and x <= src_w - 1 and y <= src_h - 1):
                out[row, col] = np.nan
                continue
            x0 = min(int(x), src_w - 2) if src_w > 1 else 0
            y0 = min(int(y), src_h - 2) if src_h > 1 else 0
            fx = x - x0
            fy = y - y0
            x1 = min(x0 + 1, src_w - 1)
            y1 = min(y0 + 1, src_h - 1)
            value = 0.0
            for yy, wy in ((y0, 1.0 - fy), (y1, fy)):
                for xx, wx in ((x0, 1.0 - fx), (x1, fx)):
                    weight = wx * wy
                    if weight > 0.0:
                        value += weight * image[yy, xx]  # NaN neighbours propagate
            out[row, col] = value
    return out


def warp_to_rectified(image: np.ndarray, H: np.ndarray, size) -> np.ndarray:
    """Resample an image onto the rectified canvas (exact bilinear, NaN outside).

    Parameters
    ----------
    image : (H, W) float
        Original image, NaN = nodata.
    H : (3, 3) float
        Original → rectified homography.
    size : (2,) int
        (width, height) of the rectified canvas.

    Returns
    -------
    (height, width) float32
        Rectified image; NaN outside the warped image and next to nodata.
    """
    width, height = (int(s) for s in np.asarray(size).reshape(2))
    if width <= 0 or height <= 0:
        raise ParameterError(f"rectified size must be positive, got {width} x {height}")
    H_inv = np.linalg.inv(np.asarray(H, np.float64))
    return _warp_bilinear(np.ascontiguousarray(image, dtype=np.float32), H_inv, height, width)
