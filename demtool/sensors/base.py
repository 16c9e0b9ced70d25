"""The interface every sensor model implements, and the numerics the models share.

Conventions (those of the USGS Community Sensor Model, usgscsm):

- **Image coordinates** are ``(line, sample)`` in pixels, and the *centre* of the first
  (top-left) pixel is ``(0.5, 0.5)``; pixel (row r, column c) of an array is centred
  at ``(line, sample) = (r + 0.5, c + 0.5)``.  (demtool's older pinhole helpers use
  ``(u, v) = (c, r)``; :class:`~demtool.sensors.pinhole.PinholeCamera` has both.)
- **Ground coordinates** are body-fixed Cartesian XYZ in metres (the body's
  rotating frame, e.g. IAU_MOON / MOON_ME as the ISD gives it), origin at the body's
  centre.  A *height* is metres above the body's reference ellipsoid, taken as in
  usgscsm: the ellipsoid with both semi-axes raised by ``height``.
- Every method is vectorised: ``line``/``sample`` are arrays of any one shape ``S``
  (scalars included); XYZ arrays have shape ``S + (3,)``.

References: usgscsm ``src/Utilities.cpp`` (``lagrangeInterp``,
``computeDistortedFocalPlaneCoordinates``, ``computePixel``) and
``UsgsAstroLsSensorModel::losEllipsoidIntersect``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np


class Ray(NamedTuple):
    """An imaging ray: ``origin + s * direction``, s > 0 towards the scene.

    origin : S + (3,) float64, metres, body-fixed (or world) frame.
    direction : S + (3,) float64, unit vectors in the same frame.
    """

    origin: np.ndarray
    direction: np.ndarray


class SensorModel(ABC):
    """A camera model: image ↔ ground geometry in the body-fixed frame.

    Subclasses set ``name`` (str), ``lines`` and ``samples`` (image size in pixels),
    ``radii`` (semi-major, semi-minor axes in metres, or ``None`` for the synthetic
    local frame) and implement :meth:`image_to_ray`, :meth:`ground_to_image` and
    :meth:`sun_position`.
    """

    name: str = ""
    kind: str = ""
    lines: int = 0
    samples: int = 0
    radii: tuple[float, float] | None = None
    #: Times the position/pointing samples cover (:class:`demtool.sensors.coverage.Coverage`);
    #: None: not checked (frame models, models built in code).
    coverage = None

    @property
    def image_size(self) -> tuple[int, int]:
        """``(lines, samples)`` = (height, width) in pixels."""
        return int(self.lines), int(self.samples)

    @abstractmethod
    def image_to_ray(self, line, sample) -> Ray:
        """Imaging ray of image points (CSM convention: first pixel centre at 0.5, 0.5).

        Parameters
        ----------
        line, sample : array_like of shape S
            Image coordinates in pixels.

        Returns
        -------
        Ray
            ``origin`` (the sensor position at the line's exposure time) and unit
            ``direction``, both S + (3,) float64, body-fixed metres.
        """

    def image_to_ground(self, line, sample, height=0.0) -> np.ndarray:
        """Intersect the imaging rays with the ellipsoid raised by ``height``.

        Parameters
        ----------
        line, sample : array_like of shape S
            Image coordinates in pixels (CSM convention, first pixel centre at 0.5).
        height : float or array_like broadcastable to S
            Metres above the reference ellipsoid.

        Returns
        -------
        S + (3,) float64
            Body-fixed XYZ in metres.  A ray that misses returns its point closest to
            the ellipsoid, as usgscsm does; use :func:`ray_ellipsoid_intersection`
            with ``return_hit=True`` on :meth:`image_to_ray` to tell misses apart.
        """
        ray = self.image_to_ray(line, sample)
        a, b = self.radii
        return ray_ellipsoid_intersection(ray.origin, ray.direction, a, b, height)

    @abstractmethod
    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates ``(line, sample)`` of body-fixed points.

        Parameters
        ----------
        xyz : array_like, S + (3,)
            Body-fixed coordinates in metres.

        Returns
        -------
        line, sample : float64 arrays of shape S
            CSM image coordinates (first pixel centre at 0.5); points behind the
            sensor give NaN.
        """

    @abstractmethod
    def sun_position(self, line) -> np.ndarray:
        """Sun position (body-fixed metres, S + (3,)) at the exposure time of ``line``."""

    def camera_center(self, line) -> np.ndarray:
        """Sensor position (body-fixed metres, S + (3,)) at the exposure time of ``line``."""
        line = np.asarray(line, dtype=np.float64)
        samples = np.full(line.shape, 0.5 * self.samples)
        return self.image_to_ray(line, samples).origin

    def look_direction(self, line, sample) -> np.ndarray:
        """Unit look vectors (S + (3,)) of image points; same as ``image_to_ray(...).direction``."""
        return self.image_to_ray(line, sample).direction


class WidthHeightSensor(SensorModel):
    """A model that keeps its image size as ``width`` and ``height`` (pixels), as the
    pinhole family's files do (OpenCV, .tsai, CAHV*): ``lines`` is the height and
    ``samples`` the width."""

    @property
    def lines(self) -> int:  # type: ignore[override]
        return self.height

    @property
    def samples(self) -> int:  # type: ignore[override]
        return self.width


# ---------------------------------------------------------------------------------------
# Ellipsoid
# ---------------------------------------------------------------------------------------


def ray_ellipsoid_intersection(origin, direction, semi_major: float, semi_minor: float,
                               height=0.0, *, return_hit: bool = False):
    """First intersection of rays with the ellipsoid raised by ``height``.

    Follows usgscsm's ``losEllipsoidIntersect``: the ellipsoid has semi-axes
    ``(a + h, a + h, b + h)``; of the two roots the one nearer the origin is taken; a
    ray that misses (negative discriminant) returns its point of closest approach.

    Parameters
    ----------
    origin, direction : S + (3,) float
        Ray origins (metres) and directions (any length), body-fixed.
    semi_major, semi_minor : float
        Ellipsoid semi-axes in metres.
    height : float or array broadcastable to S
        Metres above the ellipsoid.
    return_hit : bool
        Also return a boolean S array, True where the ray meets the ellipsoid in
        front of its origin.

    Returns
    -------
    xyz : S + (3,) float64
    hit : S bool, when ``return_hit``
    """
    origin = np.asarray(origin, dtype=np.float64)
    direction = np.asarray(direction, dtype=np.float64)
    height = np.asarray(height, dtype=np.float64)
    ap = semi_major + height
    bp = semi_minor + height
    k = (ap * ap) / (bp * bp)
    xc, yc, zc = origin[..., 0], origin[..., 1], origin[..., 2]
    xl, yl, zl = direction[..., 0], direction[..., 1], direction[..., 2]
    at = xl * xl + yl * yl + k * zl * zl
    bt = 2.0 * (xl * xc + yl * yc + k * zl * zc)
    ct = xc * xc + yc * yc + k * zc * zc - ap * ap
    quad = bt * bt - 4.0 * at * ct
    missed = quad < 0.0
    root = np.sqrt(np.where(missed, 0.0, quad))
    s0 = -bt - root
    s1 = -bt + root
    scale = np.where(np.abs(s1) < np.abs(s0), s1, s0) / (2.0 * at)
    xyz = origin + scale[..., None] * direction
    if return_hit:
        return xyz, ~missed & (scale > 0)
    return xyz


# ---------------------------------------------------------------------------------------
# Rotations
# ---------------------------------------------------------------------------------------


def quaternion_to_matrix(q) -> np.ndarray:
    """Rotation matrices of quaternions given scalar-*last* ``(x, y, z, w)``.

    The quaternions are normalised first.  The matrix is the active rotation
    (usgscsm ``calculateRotationMatrixFromQuaternions``; Eigen's ``toRotationMatrix``;
    SPICE ``q2m`` with the scalar moved first).

    q : (..., 4) → (..., 3, 3)
    """
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = x * x - y * y - z * z + w * w
    m[..., 0, 1] = 2 * (x * y - z * w)
    m[..., 0, 2] = 2 * (x * z + y * w)
    m[..., 1, 0] = 2 * (x * y + z * w)
    m[..., 1, 1] = -x * x + y * y - z * z + w * w
    m[..., 1, 2] = 2 * (y * z - x * w)
    m[..., 2, 0] = 2 * (x * z - y * w)
    m[..., 2, 1] = 2 * (y * z + x * w)
    m[..., 2, 2] = -x * x - y * y + z * z + w * w
    return m


def matrix_to_quaternion(m) -> np.ndarray:
    """Scalar-last quaternions ``(x, y, z, w)`` of rotation matrices (..., 3, 3), w ≥ 0.

    Shepperd's method: the largest of the four squared components is computed from
    the trace, the others from the off-diagonal sums, for stability.
    """
    m = np.asarray(m, dtype=np.float64)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cand = np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2], trace], axis=-1)
    which = np.argmax(cand, axis=-1)
    q = np.empty(m.shape[:-2] + (4,))
    for case in range(4):
        sel = which == case
        if not np.any(sel):
            continue
        r = m[sel]
        if case == 3:
            s = 2.0 * np.sqrt(1.0 + r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2])
            vals = [(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                    (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s]
        else:
            i, j, k = case, (case + 1) % 3, (case + 2) % 3
            s = 2.0 * np.sqrt(1.0 + r[:, i, i] - r[:, j, j] - r[:, k, k])
            vals = [None] * 4
            vals[i] = 0.25 * s
            vals[j] = (r[:, j, i] + r[:, i, j]) / s
            vals[k] = (r[:, k, i] + r[:, i, k]) / s
            vals[3] = (r[:, k, j] - r[:, j, k]) / s
        q[sel] = np.stack(vals, axis=-1)
    q *= np.where(q[..., 3:4] < 0, -1.0, 1.0)
    return q


def slerp(q0, q1, t) -> np.ndarray:
    """Spherical linear interpolation of scalar-last quaternions (shortest path).

    q0, q1 : (..., 4); t : (...,) fraction (may lie outside [0, 1]: extrapolation, as
    ALE's ``Rotation::interpolate`` allows).
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-10
    sin_theta = np.where(small, 1.0, np.sin(theta))
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / sin_theta)
    w1 = np.where(small, t, np.sin(t * theta) / sin_theta)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------
# Lagrange interpolation of equally spaced samples (usgscsm lagrangeInterp)
# ---------------------------------------------------------------------------------------


def _lagrange_weights(tau: np.ndarray, order: int) -> np.ndarray:
    """Weights (N, order) of nodes at offsets ``-(order/2 - 1) … order/2``.

    ``w_j = Π_{m≠j} (τ − x_m) / Π_{m≠j} (x_j − x_m)``, the numerators from prefix and
    suffix products (3·order array operations instead of order²).
    """
    nodes = np.arange(order) - (order // 2 - 1)
    factors = tau[:, None] - nodes[None, :]
    left = np.ones_like(factors)
    right = np.ones_like(factors)
    left[:, 1:] = np.cumprod(factors[:, :-1], axis=1)
    right[:, :-1] = np.cumprod(factors[:, :0:-1], axis=1)[:, ::-1]
    denominators = np.array([np.prod([nodes[j] - nodes[m] for m in range(order) if m != j])
                             for j in range(order)], dtype=np.float64)
    return left * right / denominators


def lagrange_interp(values, t0: float, dt: float, times, max_order: int = 8) -> np.ndarray:
    """Lagrange interpolation of equally spaced samples, as usgscsm's ``lagrangeInterp``.

    The order is 8 in the interior and falls to 6, 4, 2 within three samples of
    either end (never above ``max_order``); times beyond the ends extrapolate from the
    first or last interval.

    Parameters
    ----------
    values : (n, k) float
        Samples at times ``t0 + i * dt``, i = 0 … n-1 (n ≥ 2).
    t0, dt : float
        Time of the first sample and spacing (seconds).
    times : (N,) float
        Query times.
    max_order : int
        Highest order used (usgscsm: 8 for positions, 4 for its ``platformFlag = 0``).

    Returns
    -------
    (N, k) float64
    """
    values = np.asarray(values, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    n = len(values)
    if n < 2:
        raise ValueError("Lagrange interpolation needs at least 2 samples")
    fndex = (times - t0) / dt
    index = np.clip(np.trunc(fndex), 0, n - 2).astype(np.int64)
    order = np.full(index.shape, 2)
    order[(index >= 1) & (index < n - 2)] = 4
    order[(index >= 2) & (index < n - 3)] = 6
    order[(index >= 3) & (index < n - 4)] = 8
    order = np.minimum(order, max_order)
    tau = fndex - index
    out = np.zeros((len(times), values.shape[1]))
    for o in (2, 4, 6, 8):
        sel = np.flatnonzero(order == o)
        if not len(sel):
            continue
        weights = _lagrange_weights(tau[sel], o)
        first = index[sel] - o // 2 + 1
        for j in range(o):
            out[sel] += weights[:, j:j + 1] * values[first + j]
    return out


# ---------------------------------------------------------------------------------------
# Detector ↔ focal plane (usgscsm computeDistortedFocalPlaneCoordinates / computePixel)
# ---------------------------------------------------------------------------------------


class Detector(NamedTuple):
    """Interior orientation shared by the CSM frame and line-scan models.

    ``itrans_sample``/``itrans_line`` are ALE's ``focal2pixel_samples/lines``
    (pixels per mm, affine: ``pixel = c0 + c1 x + c2 y``); ``center_*`` the detector
    centre (``detector_center``); ``start_*`` the first detector pixel of the image;
    ``*_summing`` the detector summing.
    """

    itrans_sample: np.ndarray
    itrans_line: np.ndarray
    center_sample: float
    center_line: float
    start_sample: float = 0.0
    start_line: float = 0.0
    sample_summing: float = 1.0
    line_summing: float = 1.0

    def to_focal_plane(self, line, sample) -> tuple[np.ndarray, np.ndarray]:
        """Image (line, sample) → distorted focal-plane (x, y) in mm."""
        s, ln = self.itrans_sample, self.itrans_line
        det_sample = np.asarray(sample, dtype=np.float64) * self.sample_summing \
            + self.start_sample
        det_line = np.asarray(line, dtype=np.float64) * self.line_summing + self.start_line
        t1 = det_line - self.center_line - ln[0]
        t2 = det_sample - self.center_sample - s[0]
        det = ln[1] * s[2] - ln[2] * s[1]
        return (s[2] * t1 - ln[2] * t2) / det, (-s[1] * t1 + ln[1] * t2) / det

    def to_pixel(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Distorted focal-plane (x, y) in mm → image (line, sample)."""
        s, ln = self.itrans_sample, self.itrans_line
        det_sample = s[0] + s[1] * x + s[2] * y + self.center_sample
        det_line = ln[0] + ln[1] * x + ln[2] * y + self.center_line
        return ((det_line - self.start_line) / self.line_summing,
                (det_sample - self.start_sample) / self.sample_summing)
