"""Frame (framing) camera: usgscsm's ``UsgsAstroFrameSensorModel``.

One exposure: the sensor position ``C`` and the sensor-to-body rotation ``R`` are
fixed.  A distorted focal-plane point ``(x, y)`` (mm, from the detector by
``focal2pixel``) is undistorted to ``(u, v)``; its look vector in the body frame is
``R @ (u, v, f)`` (usgscsm's frame camera looks along its +z axis).  Ground to image
is the exact inverse: ``c = Rᵀ (X − C)``, ``(u, v) = f c_xy / c_z``, distortion
applied, then the detector affine to pixels.

Reference: DOI-USGS/usgscsm ``src/UsgsAstroFrameSensorModel.cpp`` (``imageToGround``,
``groundToImage``, ``imageToRemoteImagingLocus``).
"""

from __future__ import annotations

import numpy as np

from demtool.sensors.base import Detector, Ray, SensorModel
from demtool.sensors.distortion import Distortion


class FrameSensor(SensorModel):
    """A CSM frame camera in a body-fixed frame.

    Parameters
    ----------
    position : (3,) float
        Sensor position, body-fixed metres.
    rotation : (3, 3) float
        Sensor-to-body rotation (columns: the sensor axes in the body frame).
    focal_length : float
        Millimetres.
    detector : Detector
        Interior orientation (focal2pixel, detector centre, start, summing).
    distortion : Distortion
        Lens distortion in focal-plane millimetres.
    lines, samples : int
        Image size in pixels.
    radii : (float, float)
        Semi-major and semi-minor axes of the body, metres.
    sun : (3,) float
        Sun position, body-fixed metres.
    name : str
        Image identifier.
    z_direction : float
        +1: the camera looks along its +z axis, rays ``R (u, v, f)`` (usgscsm);
        −1: along −z, rays ``R (u, v, −f)`` (ISIS's ``zDirection``, e.g. Apollo Metric).
    """

    kind = "frame"

    def __init__(self, *, position, rotation, focal_length: float, detector: Detector,
                 distortion: Distortion | None = None, lines: int, samples: int,
                 radii: tuple[float, float], sun=(0.0, 0.0, 0.0), name: str = "",
                 time: float = 0.0, z_direction: float = 1.0):
        self.position = np.asarray(position, dtype=np.float64).reshape(3)
        self.rotation = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
        self.focal_length = float(focal_length)
        self.detector = detector
        self.distortion = distortion if distortion is not None else Distortion()
        self.lines = int(lines)
        self.samples = int(samples)
        self.radii = (float(radii[0]), float(radii[1]))
        self.sun = np.asarray(sun, dtype=np.float64).reshape(3)
        self.name = str(name)
        self.time = float(time)
        self.z_direction = 1.0 if z_direction >= 0 else -1.0
        # usgscsm's frame look vector is R (u, v, f); some ISDs' attitude puts the body on
        # the −z side.  Its intersection takes the root nearest the sensor whatever its
        # sign, so both are the same model; rays here point towards the body.
        self._sign = (-1.0 if np.dot(self.z_direction * self.rotation[:, 2], self.position) > 0
                      else 1.0)

    def __repr__(self) -> str:
        return (f"FrameSensor(name={self.name!r}, size={self.lines}x{self.samples}, "
                f"f={self.focal_length} mm, distortion={self.distortion.model})")

    def image_to_ray(self, line, sample) -> Ray:
        """Imaging rays of image points; see :meth:`SensorModel.image_to_ray`.

        The first pixel's centre is at ``(line, sample) = (0.5, 0.5)``.
        """
        line, sample = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                           np.asarray(sample, dtype=np.float64))
        x, y = self.detector.to_focal_plane(line, sample)
        u, v = self.distortion.remove(x, y)
        r = self.rotation
        f = self.focal_length * self.z_direction
        look = (u[..., None] * r[:, 0] + v[..., None] * r[:, 1] + f * r[:, 2])
        look *= self._sign / np.linalg.norm(look, axis=-1, keepdims=True)
        origin = np.broadcast_to(self.position, look.shape).copy()
        return Ray(origin, look)

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates of body-fixed points (N.B. CSM: first pixel centre 0.5).

        xyz : S + (3,) metres → (line, sample) arrays of shape S; NaN behind the sensor.
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        cam = (xyz - self.position) @ self.rotation  # Rᵀ (X − C) for each point
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.z_direction * self.focal_length * cam[..., 0] / cam[..., 2]
            v = self.z_direction * self.focal_length * cam[..., 1] / cam[..., 2]
        x, y = self.distortion.apply(u, v)
        line, sample = self.detector.to_pixel(x, y)
        behind = ~(self._sign * self.z_direction * cam[..., 2] > 0)
        line = np.where(behind, np.nan, line)
        sample = np.where(behind, np.nan, sample)
        return line, sample

    def sun_position(self, line) -> np.ndarray:
        """Sun position (body-fixed metres), the same for every line of a frame."""
        shape = np.shape(line)
        return np.broadcast_to(self.sun, shape + (3,)).copy()

    def camera_center(self, line) -> np.ndarray:
        """Sensor position (body-fixed metres), S + (3,)."""
        return np.broadcast_to(self.position, np.shape(line) + (3,)).copy()

    @property
    def boresight(self) -> np.ndarray:
        """Unit look direction of the optical axis in the body frame, (3,)."""
        return self._sign * self.z_direction * self.rotation[:, 2]
