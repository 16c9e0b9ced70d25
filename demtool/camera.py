"""Pinhole cameras: projection, rays, triangulation, OpenCV and COLMAP conventions.

Convention (OpenCV, and COLMAP's ``cam_from_world``): a world point X maps to camera
coordinates ``x_cam = R @ X + t`` (x right, y down, z forward) and to pixel
coordinates ``u = fx * x / z + cx``, ``v = fy * y / z + cy``.  The centre of pixel
(row r, column c) is at (u, v) = (c, r).  COLMAP puts the centre of the top-left
pixel at (0.5, 0.5); :func:`from_pycolmap` and :func:`to_pycolmap` shift by half a
pixel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera.

    Attributes
    ----------
    K : (3, 3) float64
        Intrinsic matrix (focal lengths and principal point in pixels).
    R : (3, 3) float64
        World-to-camera rotation.
    t : (3,) float64
        World-to-camera translation (metres): ``x_cam = R @ X + t``.
    width, height : int
        Image size in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # -- geometry ------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,) metres: ``C = -R.T @ t``."""
        return -self.R.T @ self.t

    @property
    def axis(self) -> np.ndarray:
        """Unit viewing direction (camera +z) in world coordinates, (3,)."""
        return self.R[2].copy()

    @property
    def P(self) -> np.ndarray:
        """3×4 projection matrix ``K [R | t]``."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def focal_px(self) -> float:
        """Mean focal length in pixels."""
        return 0.5 * (self.K[0, 0] + self.K[1, 1])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) → camera coordinates (N, 3)."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points.

        Parameters
        ----------
        points : (N, 3) or (3,) float
            World coordinates in metres.

        Returns
        -------
        (N, 2) or (2,) float64
            Pixel coordinates (u, v); NaN for points at or behind the camera.
        """
        pts = np.asarray(points, dtype=np.float64)
        single = pts.ndim == 1
        cam = self.to_camera(np.atleast_2d(pts))
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = cam @ self.K.T
            uv = uvw[:, :2] / uvw[:, 2:3]
        uv[cam[:, 2] <= 0] = np.nan
        return uv[0] if single else uv

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Depth (camera z, metres) of world points (N, 3) → (N,)."""
        return self.to_camera(np.atleast_2d(points))[:, 2]

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Back-project pixels to unit ray directions in world coordinates.

        Parameters
        ----------
        pixels : (N, 2) float
            Pixel coordinates (u, v).

        Returns
        -------
        (N, 3) float64
            Unit directions; the ray of pixel i is ``center + s * rays[i]``, s > 0.
        """
        uv = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        homogeneous = np.column_stack([uv, np.ones(len(uv))])
        directions_cam = homogeneous @ np.linalg.inv(self.K).T
        directions = directions_cam @ self.R  # R.T @ d for each row
        return directions / np.linalg.norm(directions, axis=1, keepdims=True)

    def backproject(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """World points at the given camera depths (z, metres) along the pixel rays, (N, 3)."""
        uv = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        homogeneous = np.column_stack([uv, np.ones(len(uv))])
        cam = (homogeneous @ np.linalg.inv(self.K).T) * np.asarray(depth, dtype=np.float64)[:, None]
        return (cam - self.t) @ self.R

    def as_dict(self) -> dict:
        """Plain-array form (for tags and JSON)."""
        return {"K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
                "width": self.width, "height": self.height}


def look_at(center: Sequence[float], target: Sequence[float], up: Sequence[float] = (0, 1, 0),
            *, focal_px: float, width: int, height: int) -> PinholeCamera:
    """Camera at ``center`` looking at ``target``, image "up" as close to ``up`` as possible.

    Parameters
    ----------
    center, target : (3,) float
        World coordinates, metres.
    up : (3,) float
        World direction that should appear as image up (−v).  For a nadir camera with
        up = +Y (north), image right is east and image down is south.
    focal_px : float
        Focal length in pixels; the principal point is the image centre.
    """
    c = np.asarray(center, dtype=np.float64)
    z_axis = np.asarray(target, dtype=np.float64) - c
    z_axis /= np.linalg.norm(z_axis)
    up_vec = np.asarray(up, dtype=np.float64)
    y_axis = -(up_vec - np.dot(up_vec, z_axis) * z_axis)  # image down
    norm = np.linalg.norm(y_axis)
    if norm < 1e-9:
        raise ValueError("look_at: the up vector is parallel to the viewing direction")
    y_axis /= norm
    x_axis = np.cross(y_axis, z_axis)
    R = np.vstack([x_axis, y_axis, z_axis])
    K = np.array([[focal_px, 0.0, (width - 1) / 2.0],
                  [0.0, focal_px, (height - 1) / 2.0],
                  [0.0, 0.0, 1.0]])
    return PinholeCamera(K=K, R=R, t=-R @ c, width=width, height=height)


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


def cameras_to_arrays(names: Sequence[str], cameras: Sequence[PinholeCamera]) -> dict:
    """Arrays for a ``cameras`` NPZ (see ``io.NPZ_SCHEMAS['cameras']``)."""
    return {
        "names": np.asarray(list(names), dtype=str),
        "K": np.stack([c.K for c in cameras]),
        "R": np.stack([c.R for c in cameras]),
        "t": np.stack([c.t for c in cameras]),
        "width": np.asarray([c.width for c in cameras], dtype=np.int64),
        "height": np.asarray([c.height for c in cameras], dtype=np.int64),
    }


def cameras_from_arrays(arrays: dict) -> dict[str, PinholeCamera]:
    """Cameras by name from a ``cameras`` NPZ's arrays (or a bundle's, keyed by image name)."""
    names = arrays["names"] if "names" in arrays else arrays["image_names"]
    return {
        str(name): PinholeCamera(K=arrays["K"][i], R=arrays["R"][i], t=arrays["t"][i],
                                 width=int(arrays["width"][i]), height=int(arrays["height"][i]))
        for i, name in enumerate(names)
    }
