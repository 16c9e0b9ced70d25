"""Pinhole cameras: projection, rays, triangulation, OpenCV and COLMAP conventions.

Convention (OpenCV, and COLMAP's ``cam_from_world``): a world point X maps to camera
coordinates ``x_cam = R @ X + t`` (x right, y down, z forward) and to pixel
coordinates ``u = fx * x / z + cx``, ``v = fy * y / z + cy``.  The centre of pixel
(row r, column c) is at (u, v) = (c, r).  COLMAP puts the centre of the top-left
pixel at (0.5, 0.5); :func:`from_pycolmap` and :func:`to_pycolmap` shift by half a
pixel.

:class:`PinholeCamera`, :func:`look_at` and the ``cameras`` NPZ helpers live in
:mod:`demtool.sensors.pinhole` (the pinhole is one implementation of the common
sensor-model interface) and are re-exported here unchanged.
"""

from __future__ import annotations

import numpy as np

from demtool.sensors.pinhole import PinholeCamera, cameras_from_arrays, cameras_to_arrays, look_at

__all__ = ["PinholeCamera", "cameras_from_arrays", "cameras_to_arrays", "from_opencv",
           "from_pycolmap", "look_at", "to_opencv", "to_pycolmap", "triangulate_linear",
           "triangulate_midpoint"]


# ----------------------------------------------------------------------------------------
# Triangulation
# ----------------------------------------------------------------------------------------


def triangulate_linear(camera_a: PinholeCamera, camera_b: PinholeCamera,
                       pixels_a: np.ndarray, pixels_b: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of corresponding pixels in two views.

    Hartley & Zisserman (2004), *Multiple View Geometry*, §12.2, homogeneous method.

    Parameters
    ----------
    pixels_a, pixels_b : (N, 2) float
        Corresponding pixel coordinates (u, v).

    Returns
    -------
    (N, 3) float64
        World points.
    """
    a = np.atleast_2d(np.asarray(pixels_a, dtype=np.float64))
    b = np.atleast_2d(np.asarray(pixels_b, dtype=np.float64))
    Pa, Pb = camera_a.P, camera_b.P
    A = np.stack([
        a[:, 0:1] * Pa[2] - Pa[0],
        a[:, 1:2] * Pa[2] - Pa[1],
        b[:, 0:1] * Pb[2] - Pb[0],
        b[:, 1:2] * Pb[2] - Pb[1],
    ], axis=1)  # (N, 4, 4)
    # Normalise rows for conditioning before the SVD.
    A /= np.linalg.norm(A, axis=2, keepdims=True)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1]
    return X[:, :3] / X[:, 3:4]


def triangulate_midpoint(camera_a: PinholeCamera, camera_b: PinholeCamera,
                         pixels_a: np.ndarray, pixels_b: np.ndarray,
                         return_distance: bool = False):
    """Midpoint triangulation: the point halfway along the shortest segment between rays.

    Returns
    -------
    points : (N, 3) float64
        World points.
    distance : (N,) float64, optional
        Length of the shortest segment between the two rays (metres), a measure of the
        match's inconsistency; returned when ``return_distance``.
    """
    ca, cb = camera_a.center, camera_b.center
    da = camera_a.rays(pixels_a)
    db = camera_b.rays(pixels_b)
    w0 = ca - cb
    a = np.sum(da * da, axis=1)
    b = np.sum(da * db, axis=1)
    c = np.sum(db * db, axis=1)
    d = da @ w0
    e = db @ w0
    denom = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        sa = (b * e - c * d) / denom
        sb = (a * e - b * d) / denom
    pa = ca + sa[:, None] * da
    pb = cb + sb[:, None] * db
    points = 0.5 * (pa + pb)
    parallel = np.abs(denom) < 1e-12
    points[parallel] = np.nan
    if return_distance:
        return points, np.linalg.norm(pa - pb, axis=1)
    return points


# ----------------------------------------------------------------------------------------
# Conventions of other tools
# ----------------------------------------------------------------------------------------


def to_opencv(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(K, rvec, tvec)`` for ``cv2.projectPoints`` (Rodrigues rotation vector)."""
    import cv2

    rvec, _ = cv2.Rodrigues(camera.R)
    return camera.K.copy(), rvec.reshape(3), camera.t.copy()


def from_opencv(K: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, width: int,
                height: int) -> PinholeCamera:
    """Camera from OpenCV's ``K``, Rodrigues ``rvec`` and ``tvec``."""
    import cv2

    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return PinholeCamera(K=K, R=R, t=np.asarray(tvec).reshape(3), width=width, height=height)


def from_pycolmap(image, camera) -> PinholeCamera:
    """Camera from a pycolmap ``Image`` (its ``cam_from_world`` pose) and ``Camera``.

    COLMAP's pixel convention puts the top-left pixel's centre at (0.5, 0.5), so the
    principal point is shifted by −0.5 px into demtool's convention.
    """
    pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
    matrix = np.asarray(pose.matrix(), dtype=np.float64)
    K = np.asarray(camera.calibration_matrix(), dtype=np.float64).copy()
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    return PinholeCamera(K=K, R=matrix[:, :3], t=matrix[:, 3], width=camera.width,
                         height=camera.height)


def to_pycolmap(camera: PinholeCamera, camera_id: int = 1):
    """A pycolmap ``PINHOLE`` Camera and ``Rigid3d`` pose (cam_from_world) for ``camera``."""
    import pycolmap

    K = camera.K
    colmap_camera = pycolmap.Camera(
        model="PINHOLE", width=camera.width, height=camera.height,
        params=[K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5], camera_id=camera_id)
    pose = pycolmap.Rigid3d(pycolmap.Rotation3d(camera.R), camera.t)
    return colmap_camera, pose


