"""A rover-like stereo pair in a local frame: two pinholes 1 m above a few metres of ground.

Rovers, landers, lab rigs and drones carry calibrated cameras whose models live in a
local metric frame (no body, no map).  This scene is their synthetic stand-in, with
exact truth:

* **Frame**: X right, Y forward, Z up (metres), the ground near Z = 0; or the same scene
  in a **z-down** frame (X right, Y backward, Z down: the scene rotated 180° about X,
  as rover frames often have gravity along +Z), where the up axis is ``(0, 0, −1)``.
* **Ground**: ``z = height_xy(x, y)`` — a gentle tilt, a few smooth mounds (rocks and
  dunes, 5 to 25 cm high) and a shallow depression, defined in the Z-up frame.
* **Albedo**: band-limited noise on a 2 cm lattice, two scales (gravel and patches),
  sampled bilinearly.
* **Cameras**: ideal :class:`demtool.sensors.pinhole.PinholeCamera` s (no body,
  ``radii`` None) at ``(∓baseline/2, 0, camera_height)``, parallel, pitched down so
  the image spans from about 1.2 m to about 6 m of ground ahead (the scene about 5 m
  deep).  Images are ray-cast (2 × 2 supersampling): each ray marches along its length
  in 5 cm steps to the first sign change of ``z − height_xy`` and is bisected there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from demtool.sensors.pinhole import PinholeCamera, look_at

#: the z-down frame's points are ``Z_DOWN @ p`` of the Z-up frame's (180° about X)
Z_DOWN = np.diag([1.0, -1.0, -1.0])

_MOUNDS = (  # x, y, sigma, height (metres), in the Z-up frame
    (-0.6, 2.0, 0.18, 0.12),
    (0.5, 2.8, 0.25, 0.22),
    (-1.0, 4.0, 0.45, 0.25),
    (1.2, 4.6, 0.30, 0.15),
    (0.0, 1.6, 0.10, 0.05),
)


def height_xy(x, y) -> np.ndarray:
    """Ground height (m, Z-up frame) at (x, y) metres: tilt, mounds and a depression."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    h = 0.03 * x - 0.02 * (y - 3.0)
    for mx, my, sigma, amplitude in _MOUNDS:
        h = h + amplitude * np.exp(-((x - mx) ** 2 + (y - my) ** 2) / (2 * sigma * sigma))
    h = h - 0.10 * np.exp(-(((x - 0.2) ** 2 + (y - 3.6) ** 2) / 0.35 ** 2) ** 2)
    return h


@dataclass(frozen=True)
class RoverScene:
    """The pair and its truth.

    left, right : PinholeCamera, in the scene's frame (``z_down`` or Z up)
    left_image, right_image : (height, width) float32, 0 … 1
    z_down : bool, whether the frame is the z-down one
    up : (3,) float, the up axis in the scene's frame
    camera_height_m : float, camera centres above the ground's Z = 0
    """

    left: PinholeCamera
    right: PinholeCamera
    left_image: np.ndarray
    right_image: np.ndarray
    z_down: bool
    up: np.ndarray
    camera_height_m: float

    def truth_height(self, points) -> np.ndarray:
        """Ground height along ``up`` (m) under points of the scene's frame, (N, 3)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.z_down:
            p = p @ Z_DOWN  # Z_DOWN is its own inverse
        return height_xy(p[:, 0], p[:, 1])  # along up = the Z-up frame's z

    def truth_xyz(self, points) -> np.ndarray:
        """The ground point under (N, 3) points of the scene's frame (same frame)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        q = p @ Z_DOWN if self.z_down else p.copy()
        q[:, 2] = height_xy(q[:, 0], q[:, 1])
        return q @ Z_DOWN if self.z_down else q


def _albedo(seed: int, extent=(-4.0, 4.0, 0.0, 8.0), cell: float = 0.02):
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    x0, x1, y0, y1 = extent
    shape = (int(round((y1 - y0) / cell)) + 1, int(round((x1 - x0) / cell)) + 1)
    fine = gaussian_filter(rng.normal(size=shape), 1.0)
    coarse = gaussian_filter(rng.normal(size=shape), 6.0)
    field = fine / fine.std() + 0.8 * coarse / coarse.std()
    field = 0.5 + 0.12 * field
    return np.clip(field, 0.05, 0.95), (x0, y0, cell)


@njit(cache=True)
def _height_one(x: float, y: float, mounds: np.ndarray) -> float:  # pragma: no cover
    """:func:`height_xy` of one point (terms below 1e-9 m skipped)."""
    h = 0.03 * x - 0.02 * (y - 3.0)
    for k in range(mounds.shape[0]):
        dx, dy, sigma = x - mounds[k, 0], y - mounds[k, 1], mounds[k, 2]
        q = (dx * dx + dy * dy) / (2 * sigma * sigma)
        if q < 25.0:
            h += mounds[k, 3] * np.exp(-q)
    r2 = ((x - 0.2) ** 2 + (y - 3.6) ** 2) / 0.35 ** 2
    if r2 < 5.0:
        h -= 0.10 * np.exp(-r2 * r2)
    return h


@njit(cache=True, parallel=True)
def _ground_hits_kernel(origin, direction, mounds, step, top, bottom):  # pragma: no cover
    n = direction.shape[0]
    hit = np.full((n, 3), np.nan)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in prange(n):
        dx, dy, dz = direction[i, 0], direction[i, 1], direction[i, 2]
        if dz > -1e-9:
            continue
        s = max((top - oz) / dz, 0.0)
        s_end = (bottom - oz) / dz
        f_prev = oz + s * dz - _height_one(ox + s * dx, oy + s * dy, mounds)
        while s < s_end:
            s_next = s + step
            f_next = oz + s_next * dz - _height_one(ox + s_next * dx, oy + s_next * dy, mounds)
            if f_prev > 0 and f_next <= 0:
                lo, hi = s, s_next
                for _ in range(30):
                    mid = 0.5 * (lo + hi)
                    if oz + mid * dz - _height_one(ox + mid * dx, oy + mid * dy, mounds) <= 0:
                        hi = mid
                    else:
                        lo = mid
                m = 0.5 * (lo + hi)
                hit[i, 0], hit[i, 1], hit[i, 2] = ox + m * dx, oy + m * dy, oz + m * dz
                break
            s, f_prev = s_next, f_next
    return hit


def _ground_hits(origin: np.ndarray, direction: np.ndarray, *, step: float = 0.05,
                 top: float = 0.45, bottom: float = -0.3) -> np.ndarray:
    """First intersection of rays (Z-up frame) with the ground; NaN where none.

    The ground lies between Z = ``bottom`` and ``top``: each ray marches from where it
    crosses ``top`` to where it crosses ``bottom`` in ``step`` metre steps, and the first
    step that goes below the ground is bisected (30 halvings).
    """
    return _ground_hits_kernel(np.asarray(origin, dtype=np.float64),
                               np.ascontiguousarray(direction, dtype=np.float64),
                               np.asarray(_MOUNDS, dtype=np.float64), step, top, bottom)


def render(camera: PinholeCamera, albedo, origin_cell, *, z_down: bool,
           supersample: int = 2, noise: float = 0.003, rng=None) -> np.ndarray:
    """Image of the ground through ``camera`` (float32 0 … 1; sky = 0.02)."""
    from scipy.ndimage import map_coordinates

    k = supersample
    offsets = (np.arange(k) + 0.5) / k - 0.5
    rows, cols = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    total = np.zeros(rows.shape)
    x0, y0, cell = origin_cell
    for dv in offsets:
        for du in offsets:
            pixels = np.stack([(cols + du).ravel(), (rows + dv).ravel()], axis=-1)
            direction = camera.rays(pixels)
            direction = direction / np.linalg.norm(direction, axis=1, keepdims=True)
            center = camera.center
            if z_down:
                direction, center = direction @ Z_DOWN, Z_DOWN @ center
            hit = _ground_hits(center, direction)
            value = np.full(len(hit), 0.02)
            ok = np.isfinite(hit).all(axis=1)
            value[ok] = map_coordinates(albedo, [(hit[ok, 1] - y0) / cell,
                                                 (hit[ok, 0] - x0) / cell],
                                        order=1, mode="reflect")
            total += value.reshape(rows.shape)
    image = total / (k * k)
    if rng is not None and noise > 0:
        image = image + rng.normal(0.0, noise, image.shape)
    return np.clip(image, 0.0, 1.0).astype(np.float32)


def make_rover_pair(*, width: int = 320, height: int = 240, focal_px: float = 448.0,
                    baseline_m: float = 0.3, camera_height_m: float = 1.0,
                    pitch_deg: float = 25.0, z_down: bool = False, seed: int = 0,
                    supersample: int = 2) -> RoverScene:
    """A seeded rover-like stereo pair (see the module docstring).

    Parameters
    ----------
    width, height : int, image size, pixels
    focal_px : float, focal length, pixels (448 px: 39° × 30° field of view at 320 × 240)
    baseline_m : float, distance between the camera centres, metres (along X)
    camera_height_m : float, camera centres above Z = 0, metres
    pitch_deg : float, boresight below the horizontal, degrees
    z_down : bool, give the cameras in the z-down frame (up = (0, 0, −1))
    seed : int
    supersample : int, rays per pixel side

    Returns
    -------
    RoverScene
    """
    rng = np.random.default_rng(seed)
    albedo, origin_cell = _albedo(seed)
    pitch = np.radians(pitch_deg)
    look = np.array([0.0, np.cos(pitch), -np.sin(pitch)])
    cameras = []
    for name, x in (("left", -0.5 * baseline_m), ("right", 0.5 * baseline_m)):
        center = np.array([x, 0.0, camera_height_m])
        cam = look_at(center, center + look, up=(0.0, 0.0, 1.0), focal_px=focal_px,
                      width=width, height=height)
        if z_down:  # the same camera, points given in the z-down frame
            cam = PinholeCamera(K=cam.K, R=cam.R @ Z_DOWN, t=cam.t, width=width,
                                height=height, name=name)
        else:
            cam = PinholeCamera(K=cam.K, R=cam.R, t=cam.t, width=width, height=height,
                                name=name)
        cameras.append(cam)
    images = [render(cam, albedo, origin_cell, z_down=z_down, supersample=supersample,
                     rng=rng) for cam in cameras]
    up = np.array([0.0, 0.0, -1.0]) if z_down else np.array([0.0, 0.0, 1.0])
    return RoverScene(cameras[0], cameras[1], images[0], images[1], z_down, up,
                      camera_height_m)
