"""The models a control-network adjustment produces (:mod:`demtool.bundle.network`), in
memory and written back in the formats they came in.

* :class:`CorrectedSensor`: a sensor model with the adjustment's correction
  ``θ`` (pointing polynomial in time, position bias) applied, behind the common
  interface (rays, projections), for ``bundle.npz``'s local pinholes and for checks.
* :func:`adjust_isd_timed`: an ALE ISD whose ``instrument_pointing`` quaternions are
  turned by the correction at each record's time and whose ``instrument_position``
  states are moved by the bias, so that any ISD reader (usgscsm, demtool) sees the
  adjusted model (as :func:`demtool.bundle.writeback.adjust_isd` does for a constant
  offset; ISIS's jigsaw updates a cube's SPICE tables the same way).  With the body
  rotation ``B(t)`` (J2000 → body), a body-frame rotation ``M`` of the sensor becomes
  ``Q' = Q Bᵀ Mᵀ B`` of the J2000-to-sensor pointing, and a body-frame shift ``d`` of
  the position ``p_J2000' = p_J2000 + Bᵀ d``.
* :func:`frame_offset`: the constant :class:`PoseOffset` of a frame camera's correction
  (``.tsai`` files go through :func:`demtool.bundle.writeback.adjust_tsai`).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import numpy as np

from demtool.bundle.network_geometry import ImageFrame, _line_times, project_corrected
from demtool.bundle.offsets import PoseOffset, rotation_matrices
from demtool.sensors.base import Ray, SensorModel, matrix_to_quaternion, quaternion_to_matrix


def rotation_vectors(frame: ImageFrame, theta: np.ndarray, t) -> np.ndarray:
    """Body-frame rotation vectors (..., 3), radians, of the correction at times ``t``
    (seconds from the image's centre)."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    return (theta[0:3] + theta[3:6] * t + theta[6:9] * t ** 2) @ frame.axes.T


class CorrectedSensor(SensorModel):
    """``model`` corrected by ``theta`` (12,), SI units (:data:`demtool.bundle.network.
    PARAMETER_NAMES`) in the axes of ``frame``."""

    def __init__(self, model: SensorModel, frame: ImageFrame, theta: np.ndarray):
        self.model, self.frame, self.theta = model, frame, np.asarray(theta, dtype=float)
        self.name, self.kind = model.name, model.kind
        self.lines, self.samples, self.radii = model.lines, model.samples, model.radii

    def image_to_ray(self, line, sample) -> Ray:
        ray = self.model.image_to_ray(line, sample)
        line = np.broadcast_to(np.asarray(line, dtype=np.float64), ray.origin.shape[:-1])
        turn = rotation_matrices(rotation_vectors(self.frame, self.theta,
                                                  _line_times(self.model, line)))
        return Ray(ray.origin + self.frame.track @ self.theta[9:12],
                   np.einsum("...ij,...j->...i", turn, ray.direction))

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        xyz = np.asarray(xyz, dtype=np.float64)
        shape = xyz.shape[:-1]
        line, sample = project_corrected(self.model, self.frame, self.theta,
                                         xyz.reshape(-1, 3))
        return line.reshape(shape), sample.reshape(shape)

    def sun_position(self, line) -> np.ndarray:
        return self.model.sun_position(line)

    def camera_center(self, line) -> np.ndarray:
        return np.asarray(self.model.camera_center(line)) + self.frame.track @ self.theta[9:12]


def adjust_isd_timed(isd: Mapping[str, Any], frame: ImageFrame, theta: np.ndarray, *,
                     center_time: float) -> dict[str, Any]:
    """A copy of an ALE ISD with the correction ``theta`` applied (module docstring);
    ``center_time``: the ephemeris seconds the correction's time counts from."""
    from demtool.bundle.writeback import _UNITS, _body

    out = copy.deepcopy(dict(isd))
    body = _body(isd)
    shift = frame.track @ np.asarray(theta)[9:12]
    position = out["instrument_position"]
    scale = _UNITS[str(position.get("unit", "km")).lower()]
    times = np.asarray(position["ephemeris_times"], dtype=np.float64).reshape(-1)
    b = body.matrices_at(times)
    moved = np.asarray(position["positions"], dtype=np.float64).reshape(-1, 3) + \
        np.einsum("nji,j->ni", b, shift) / scale
    position["positions"] = moved.tolist()  # a constant shift leaves the velocities
    pointing = out["instrument_pointing"]
    p_times = np.asarray(pointing["ephemeris_times"], dtype=np.float64).reshape(-1)
    q = quaternion_to_matrix(np.asarray(pointing["quaternions"], dtype=np.float64)
                             .reshape(-1, 4)[:, [1, 2, 3, 0]])
    b = body.matrices_at(p_times)
    turn = rotation_matrices(rotation_vectors(frame, np.asarray(theta), p_times - center_time))
    m_new = q @ np.einsum("nji,nkj,nkl->nil", b, turn, b)  # Q Bᵀ Mᵀ B
    pointing["quaternions"] = matrix_to_quaternion(m_new)[:, [3, 0, 1, 2]].tolist()
    return out


def frame_offset(model: SensorModel, frame: ImageFrame, theta: np.ndarray) -> PoseOffset:
    """The :class:`PoseOffset` equal to a frame camera's correction: a turn by the angles
    about the camera centre, then the position bias."""
    centre = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64).reshape(3)
    return PoseOffset(frame.track @ np.asarray(theta)[9:12],
                      frame.axes @ np.asarray(theta)[0:3], centre)
