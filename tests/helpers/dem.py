"""A paraboloid surface seen by two parallel nadir cameras, for the dem tests."""

from __future__ import annotations

import numpy as np

from demtool.sensors.pinhole import PinholeCamera, look_at

ALTITUDE = 1000.0
FOCAL = 2000.0  # 0.5 m per pixel at 1000 m
SIZE = 96
BASELINE = 12.0  # parallel cameras: 24 px disparity, 75 % overlap
RECTIFY = np.array([[1.02, 0.0, 3.3], [0.0, 1.02, 2.7], [0.0, 0.0, 1.0]])


def surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Paraboloid hill, metres (world Z as a function of world X, Y)."""
    return 2.0 - 0.002 * (x**2 + y**2) + 0.01 * x


def nadir_camera(x: float = 0.0) -> PinholeCamera:
    # Parallel cameras (same rotation) so that an identical homography rectifies both.
    base = look_at([0.0, 0.0, ALTITUDE], [0.0, 0.0, 0.0], focal_px=FOCAL, width=SIZE,
                   height=SIZE)
    return PinholeCamera(K=base.K, R=base.R, t=-base.R @ np.array([x, 0.0, ALTITUDE]),
                         width=SIZE, height=SIZE)


def surface_points(camera: PinholeCamera, pixels: np.ndarray) -> np.ndarray:
    """World points where the pixels' rays meet the surface (fixed-point iteration)."""
    heights = np.zeros(len(pixels))
    for _ in range(8):
        points = camera.backproject(pixels, camera.center[2] - heights)
        heights = surface(points[:, 0], points[:, 1])
    return camera.backproject(pixels, camera.center[2] - heights)


def truth_grid(camera: PinholeCamera) -> np.ndarray:
    rows, cols = np.mgrid[:camera.height, :camera.width]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    return surface_points(camera, pixels)[:, 2].reshape(camera.height, camera.width)


def synthetic_disparity(left: PinholeCamera, right: PinholeCamera,
                        H: np.ndarray = RECTIFY) -> np.ndarray:
    """Disparity in the rectified left frame from the true geometry (x_right = x − d)."""
    width_rect, height_rect = int(SIZE * 1.02 + 6), int(SIZE * 1.02 + 6)
    rows, cols = np.mgrid[:height_rect, :width_rect]
    rect = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    homogeneous = np.column_stack([rect, np.ones(len(rect))]) @ np.linalg.inv(H).T
    left_px = homogeneous[:, :2] / homogeneous[:, 2:]
    inside = ((left_px >= 0) & (left_px <= SIZE - 1)).all(axis=1)
    disparity = np.full(len(rect), np.nan)
    points = surface_points(left, left_px[inside])
    right_px = right.project(points)
    right_h = np.column_stack([right_px, np.ones(len(right_px))]) @ H.T
    right_rect = right_h[:, :2] / right_h[:, 2:]
    ok = ((right_px >= 0) & (right_px <= SIZE - 1)).all(axis=1)
    values = rect[inside, 0] - right_rect[:, 0]
    values[~ok] = np.nan
    disparity[inside] = values
    return disparity.reshape(height_rect, width_rect)
