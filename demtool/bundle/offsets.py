"""Constant pose offsets of sensor models and the rotation-vector algebra they use.

A :class:`PoseOffset` is what the pose-prior adjustment (:mod:`demtool.bundle.priors`,
solved by :mod:`demtool.bundle.lm`) estimates per image and what
:mod:`demtool.bundle.writeback` applies to the camera files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.sensors.base import SensorModel


def rotation_matrices(rotvec) -> np.ndarray:
    """Rodrigues' formula: rotation vectors (..., 3) in radians → matrices (..., 3, 3)."""
    w = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = np.zeros(w.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    small = theta < 1e-12
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1.0 - np.cos(t)) / (t * t))
    return np.eye(3) + a * k + b * (k @ k)


def rotation_vector(matrix) -> np.ndarray:
    """Rotation vector (3,) in radians of a rotation matrix (3, 3) (angle < π)."""
    m = np.asarray(matrix, dtype=np.float64)
    cos = np.clip((np.trace(m) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    if angle < 1e-12:
        return 0.5 * axis
    return angle * axis / (2.0 * np.sin(angle))


@dataclass(frozen=True)
class PoseOffset:
    """A constant body-fixed pose offset of one sensor model.

    Attributes
    ----------
    translation : (3,) float64
        ``dC``, metres, body-fixed.
    rotation : (3,) float64
        Rotation vector ``w`` of ``dR``, radians, body-fixed.
    pivot : (3,) float64
        ``P``, the point ``dR`` turns about (the sensor position at the centre line).
    """

    translation: np.ndarray
    rotation: np.ndarray
    pivot: np.ndarray

    @property
    def matrix(self) -> np.ndarray:
        """``dR`` (3, 3)."""
        return rotation_matrices(self.rotation)

    @property
    def position_change_m(self) -> float:
        """Displacement of the sensor position at the pivot, metres."""
        return float(np.linalg.norm(self.translation))

    @property
    def pointing_change_mrad(self) -> float:
        """Rotation angle of ``dR``, milliradians."""
        return float(np.linalg.norm(self.rotation) * 1e3)

    def to_original(self, xyz) -> np.ndarray:
        """``X' = P + dRᵀ (X − P − dC)`` of body-fixed points (..., 3)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        return self.pivot + (xyz - self.pivot - self.translation) @ self.matrix

    def from_original(self, xyz) -> np.ndarray:
        """Inverse of :meth:`to_original`: ``P + dR (X' − P) + dC``."""
        xyz = np.asarray(xyz, dtype=np.float64)
        return self.pivot + (xyz - self.pivot) @ self.matrix.T + self.translation


def pivot_of(model: SensorModel) -> np.ndarray:
    """Sensor position (body-fixed metres, (3,)) at the image's centre line."""
    return np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64).reshape(3)
