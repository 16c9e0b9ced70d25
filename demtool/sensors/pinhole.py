"""Pinhole camera (OpenCV / COLMAP conventions) as a :class:`SensorModel`.

A world point X maps to camera coordinates ``x_cam = R @ X + t`` (x right, y down,
z forward), to normalised coordinates ``(x/z, y/z)``, through OpenCV's Brown
distortion (``k1, k2, p1, p2, k3``; none by default) and to pixels by ``K``.

Two pixel conventions meet here:

- demtool's own methods (:meth:`PinholeCamera.project`, :meth:`~PinholeCamera.rays`,
  :meth:`~PinholeCamera.backproject`) use ``(u, v)`` with the centre of pixel
  (row r, column c) at ``(u, v) = (c, r)``, as before;
- the :class:`SensorModel` interface (:meth:`~PinholeCamera.image_to_ray`,
  :meth:`~PinholeCamera.image_to_ground`, :meth:`~PinholeCamera.ground_to_image`)
  uses CSM's ``(line, sample)`` with the first pixel's centre at (0.5, 0.5):
  ``line = v + 0.5``, ``sample = u + 0.5``.

**World frame.**  A pinhole of the synthetic scene, of an aligned bundle or of a
``cameras.npz`` lives in demtool's local world frame (X east, Y north, Z up, metres;
see CONTRIBUTING.md), not on a body: ``radii`` is ``None`` and
:meth:`~PinholeCamera.image_to_ground` intersects the rays with the horizontal plane
``Z = height`` instead of an ellipsoid.

Triangulation of two pinholes (:func:`triangulate_linear`, :func:`triangulate_midpoint`)
and conversions to and from OpenCV and pycolmap (:func:`to_opencv`, :func:`from_opencv`,
:func:`from_pycolmap`, :func:`to_pycolmap`; COLMAP puts the centre of the top-left pixel
at (0.5, 0.5), so those two shift by half a pixel) live here too: one pinhole implementation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from demtool.sensors.base import Ray, WidthHeightSensor
from demtool.sensors.distortion import BROWN, Distortion


@dataclass(frozen=True, eq=False)
class PinholeCamera(WidthHeightSensor):
    """A pinhole camera, optionally with OpenCV Brown lens distortion.

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
    distortion : (5,) float64 or None
        OpenCV coefficients ``(k1, k2, p1, p2, k3)`` on normalised coordinates;
        ``None`` (the default) for an ideal pinhole.
    name : str
        Image name (optional).
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    distortion: np.ndarray | None = None
    name: str = ""

    kind = "pinhole"
    radii = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if self.distortion is not None:
            coefficients = np.asarray(self.distortion, dtype=np.float64).reshape(-1)
            coefficients = Distortion(BROWN, coefficients).coefficients  # checks the count
            object.__setattr__(self, "distortion",
                               None if not np.any(coefficients) else coefficients)

    # -- SensorModel attributes -----------------------------------------------------
    @property
    def lens(self) -> Distortion:
        """The lens distortion as a :class:`Distortion` (model ``none`` when ideal)."""
        if self.distortion is None:
            return Distortion()
        return Distortion(BROWN, self.distortion)

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
        """3×4 projection matrix ``K [R | t]`` (the linear part; distortion excluded)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def focal_px(self) -> float:
        """Mean focal length in pixels."""
        return 0.5 * (self.K[0, 0] + self.K[1, 1])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) → camera coordinates (N, 3)."""
        return np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    @property
    def _has_lens(self) -> bool:
        """True when the camera has lens distortion (subclasses may keep it elsewhere)."""
        return self.distortion is not None

    def _normalised_to_pixels(self, xn, yn):
        if self._has_lens:
            xn, yn = self.lens.apply(xn, yn)
        K = self.K
        return K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2]

    def _pixels_to_normalised(self, u, v):
        K = self.K
        yn = (np.asarray(v, dtype=np.float64) - K[1, 2]) / K[1, 1]
        xn = (np.asarray(u, dtype=np.float64) - K[0, 2] - K[0, 1] * yn) / K[0, 0]
        if self._has_lens:
            xn, yn = self.lens.remove(xn, yn)
        return xn, yn

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points (distortion included).

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
            if not self._has_lens:
                uvw = cam @ self.K.T
                uv = uvw[:, :2] / uvw[:, 2:3]
            else:
                u, v = self._normalised_to_pixels(cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2])
                uv = np.column_stack([u, v])
        uv[cam[:, 2] <= 0] = np.nan
        return uv[0] if single else uv

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Depth (camera z, metres) of world points (N, 3) → (N,)."""
        return self.to_camera(np.atleast_2d(points))[:, 2]

    def _camera_directions(self, pixels: np.ndarray) -> np.ndarray:
        uv = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        if not self._has_lens:
            homogeneous = np.column_stack([uv, np.ones(len(uv))])
            return homogeneous @ np.linalg.inv(self.K).T
        xn, yn = self._pixels_to_normalised(uv[:, 0], uv[:, 1])
        return np.column_stack([xn, yn, np.ones(len(xn))])

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
        directions = self._camera_directions(pixels) @ self.R  # R.T @ d for each row
        return directions / np.linalg.norm(directions, axis=1, keepdims=True)

    def backproject(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """World points at the given camera depths (z, metres) along the pixel rays, (N, 3)."""
        cam = self._camera_directions(pixels) * np.asarray(depth, dtype=np.float64)[:, None]
        return (cam - self.t) @ self.R

    def as_dict(self) -> dict:
        """Plain-array form (for tags and JSON)."""
        out = {"K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
               "width": self.width, "height": self.height}
        if self.distortion is not None:
            out["distortion"] = self.distortion.tolist()
        return out

    # -- SensorModel interface (CSM pixel convention) ---------------------------------
    def image_to_ray(self, line, sample) -> Ray:
        """Rays of image points; CSM convention (first pixel centre at (0.5, 0.5)).

        line, sample : arrays of shape S → Ray with S + (3,) origin and unit direction,
        world frame.
        """
        line, sample = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                           np.asarray(sample, dtype=np.float64))
        pixels = np.column_stack([sample.ravel() - 0.5, line.ravel() - 0.5])
        direction = self.rays(pixels).reshape(line.shape + (3,))
        origin = np.broadcast_to(self.center, direction.shape).copy()
        return Ray(origin, direction)

    def image_to_ground(self, line, sample, height=0.0) -> np.ndarray:
        """Intersect the rays with the plane ``Z = height`` of the local world frame.

        Returns S + (3,) world points (metres); NaN where the ray is parallel to the
        plane or meets it behind the camera.
        """
        ray = self.image_to_ray(line, sample)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (np.asarray(height, dtype=np.float64) - ray.origin[..., 2]) / ray.direction[..., 2]
        s = np.where(s > 0, s, np.nan)
        return ray.origin + s[..., None] * ray.direction

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """CSM ``(line, sample)`` of world points (S + (3,)); NaN behind the camera."""
        xyz = np.asarray(xyz, dtype=np.float64)
        uv = self.project(xyz.reshape(-1, 3))
        shape = xyz.shape[:-1]
        return (uv[:, 1] + 0.5).reshape(shape), (uv[:, 0] + 0.5).reshape(shape)

    def sun_position(self, line) -> np.ndarray:
        """A pinhole carries no sun; the synthetic scene's sun is in ``scene.json``."""
        raise ValueError("a pinhole camera carries no sun position; read the sun from the "
                         "scene (scene.json) or use a planetary sensor model")

    def camera_center(self, line) -> np.ndarray:
        """Camera centre (world metres), broadcast to ``shape(line) + (3,)``."""
        return np.broadcast_to(self.center, np.shape(line) + (3,)).copy()


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


def cameras_to_arrays(names: Sequence[str], cameras: Sequence[PinholeCamera]) -> dict:
    """Arrays for a ``cameras`` NPZ (see ``io.NPZ_SCHEMAS['cameras']``).

    The optional ``distortion`` array (N, 5) (OpenCV ``k1, k2, p1, p2, k3``; zeros for
    an ideal pinhole) is added when any camera has distortion.
    """
    arrays = {
        "names": np.asarray(list(names), dtype=str),
        "K": np.stack([c.K for c in cameras]),
        "R": np.stack([c.R for c in cameras]),
        "t": np.stack([c.t for c in cameras]),
        "width": np.asarray([c.width for c in cameras], dtype=np.int64),
        "height": np.asarray([c.height for c in cameras], dtype=np.int64),
    }
    for name, c in zip(names, cameras, strict=True):
        if c._has_lens and c.distortion is None:
            raise ValueError(f"camera {name!r}: a {c.lens.model} lens cannot be stored in a "
                             "cameras file (OpenCV Brown coefficients only)")
    if any(c.distortion is not None for c in cameras):
        arrays["distortion"] = np.stack([np.zeros(5) if c.distortion is None else c.distortion
                                         for c in cameras])
    return arrays


def cameras_from_arrays(arrays: dict) -> dict[str, PinholeCamera]:
    """Cameras by name from a ``cameras`` NPZ's arrays (or a bundle's, keyed by image name).

    Reads the optional ``distortion`` array when present: (N, 5) OpenCV coefficients
    (``cameras`` format version 2), or the (N, 2) COLMAP radial terms ``(k1, k2)`` a
    ``bundle`` file carries, which are Brown's with ``p1 = p2 = k3 = 0``.  Files
    without it give ideal pinholes.

    Raises
    ------
    ValueError
        ``distortion`` of the wrong shape.
    """
    names = arrays["names"] if "names" in arrays else arrays["image_names"]
    distortion = arrays.get("distortion")
    if distortion is not None:
        distortion = np.asarray(distortion, dtype=np.float64)
        if distortion.shape == (len(names), 2):
            distortion = np.column_stack([distortion, np.zeros((len(names), 3))])
        if distortion.shape not in ((len(names), 5), (len(names), 4)):
            raise ValueError(f"'distortion' has shape {distortion.shape}, expected "
                             f"({len(names)}, 5) or ({len(names)}, 2)")
    return {
        str(name): PinholeCamera(K=arrays["K"][i], R=arrays["R"][i], t=arrays["t"][i],
                                 width=int(arrays["width"][i]), height=int(arrays["height"][i]),
                                 distortion=None if distortion is None else distortion[i],
                                 name=str(name))
        for i, name in enumerate(names)
    }



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
