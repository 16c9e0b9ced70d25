"""The geometry of a control-network correction (:mod:`demtool.bundle.network`): the
image's axes, the corrected projection and its derivatives.

See :mod:`demtool.bundle.network` for the parameters and the correction
``X' = C(t) + R(w(t))ᵀ (X − C(t) − B p)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.bundle.offsets import rotation_matrices
from demtool.sensors.base import SensorModel


@dataclass(frozen=True)
class ImageFrame:
    """What a correction of one image refers to: the sample axis, line axis and boresight
    (``axes`` columns) and along track, across track, up (``track`` columns), body
    frame, at the image's centre; ``timed``: the model has exposure times (line scan)."""

    axes: np.ndarray
    track: np.ndarray
    timed: bool


def image_axes(model: SensorModel) -> ImageFrame:
    """The :class:`ImageFrame` of a model, from its rays at the image centre."""
    line, sample = 0.5 * model.lines, 0.5 * model.samples
    ray = model.image_to_ray(np.array([line, line, line + 1.0]),
                             np.array([sample, sample + 1.0, sample]))
    z = ray.direction[0] / np.linalg.norm(ray.direction[0])
    x = ray.direction[1] - ray.direction[0]
    x -= z * (x @ z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    centre = ray.origin[0]
    up = centre / np.linalg.norm(centre)
    ground = model.image_to_ground(np.array([line - 100.0, line + 100.0]),
                                   np.array([sample, sample]))
    along = ground[1] - ground[0]
    along -= up * (along @ up)
    if not np.all(np.isfinite(along)) or np.linalg.norm(along) == 0:
        along = y - up * (y @ up)
    along /= np.linalg.norm(along)
    cross = np.cross(up, along)
    return ImageFrame(np.column_stack([x, y, z]), np.column_stack([along, cross, up]),
                      hasattr(model, "line_time"))


def _line_times(model, line) -> np.ndarray:
    if hasattr(model, "line_time"):
        return np.asarray(model.line_time(line), dtype=np.float64)
    return np.zeros(np.shape(line))


def _ground_to_image(model, xyz, start_line):
    """``model.ground_to_image``, from ``start_line`` where the model takes a guess."""
    import inspect

    if start_line is not None and "start_line" in inspect.signature(
            model.ground_to_image).parameters:
        return model.ground_to_image(xyz, start_line=start_line)
    return model.ground_to_image(xyz)


def _moved(model, frame, theta, xyz, line):
    """``X'`` (M, 3) of points ``xyz`` seen on image lines ``line``, ``Rᵀ rel`` (M, 3)
    and the exposure times (M,)."""
    probe = np.where(np.isfinite(line), line, 0.5 * model.lines)
    t = _line_times(model, probe)
    w = (theta[0:3] + theta[3:6] * t[:, None] + theta[6:9] * (t ** 2)[:, None]) @ frame.axes.T
    centre = np.asarray(model.camera_center(probe), dtype=np.float64).reshape(-1, 3)
    rel = xyz - centre - frame.track @ theta[9:12]
    turned = np.einsum("mji,mj->mi", rotation_matrices(w), rel)  # Rᵀ rel
    return centre + turned, turned, t


def project_corrected(model: SensorModel, frame: ImageFrame, theta: np.ndarray, xyz,
                      start_line=None, *, iterations: int = 6):
    """Image (line, sample) of body-fixed points ``xyz`` (M, 3) through ``model`` corrected
    by ``theta`` (12,) (SI units, :data:`PARAMETER_NAMES`); ``start_line`` (M,) a first
    guess of the lines (else the prior model's).  NaN where the model has no image."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if start_line is None:
        line, sample = model.ground_to_image(xyz - frame.track @ theta[9:12])
    else:
        line = np.asarray(start_line, dtype=np.float64).copy()
    for _ in range(iterations):
        moved, _, _ = _moved(model, frame, theta, xyz, line)
        new_line, sample = _ground_to_image(model, moved, line)
        if not frame.timed:
            return new_line, sample
        finite = np.isfinite(new_line) & np.isfinite(line)
        done = not np.any(finite) or np.max(np.abs(new_line - line)[finite]) < 1e-6
        line = new_line
        if done:
            break
    return line, sample


def corrected_partials(model: SensorModel, frame: ImageFrame, theta: np.ndarray, xyz,
                       line):
    """Derivatives of (line, sample) of points ``xyz`` (M, 3) seen on lines ``line``:
    (M, 2, 12) by the parameters (internal units: µrad, µrad/s, µrad/s², m) and
    (M, 2, 3) by the point (per metre).  The model's own ground partials (forward
    differences of 1 m) chained with the correction's (small angles; the exposure
    time's dependence on the line left out, a Gauss–Newton approximation)."""
    moved, turned, t = _moved(model, frame, theta, xyz, line)
    base = np.stack(_ground_to_image(model, moved, line), axis=-1)
    ground = np.empty((len(xyz), 2, 3))
    for k in range(3):
        shifted = moved.copy()
        shifted[:, k] += 1.0
        ground[:, :, k] = np.stack(_ground_to_image(model, shifted, line), axis=-1) - base
    w = theta[0:3] + theta[3:6] * t[:, None] + theta[6:9] * (t ** 2)[:, None]
    rot_t = np.swapaxes(rotation_matrices(w @ frame.axes.T), 1, 2)  # Rᵀ
    cross = np.zeros((len(xyz), 3, 3))  # [Rᵀ rel]ₓ: d(Rᵀ rel)/dw at w
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -turned[:, 2], turned[:, 1], -turned[:, 0]
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = turned[:, 2], -turned[:, 1], turned[:, 0]
    by_angle = np.einsum("mab,mbc,cd->mad", ground, cross, frame.axes) * 1e-6  # per µrad
    params = np.concatenate([by_angle, by_angle * t[:, None, None],
                             by_angle * (t ** 2)[:, None, None],
                             -np.einsum("mab,mbc,cd->mad", ground, rot_t, frame.track)],
                            axis=2)
    return params, np.einsum("mab,mbc->mac", ground, rot_t)
