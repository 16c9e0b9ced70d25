"""Compiled kernels of the line-scan model: exposure pose and projection per point.

:func:`detector_view` is the hot part of line-scan ground → image (each iteration of
the line search evaluates it once per point): the exposure time of an image line,
the sensor position and the sensor-to-body quaternion at that time by usgscsm's
Lagrange interpolation, and the projection of a ground point onto the undistorted
focal plane.  It computes exactly what :meth:`LineScanSensor.line_time`,
:meth:`~LineScanSensor.position_at`, :meth:`~LineScanSensor.rotation_at` and
:meth:`~LineScanSensor._detector_view` compute with numpy (up to rounding), one point
per thread.

Reference: DOI-USGS/usgscsm ``src/Utilities.cpp`` (``lagrangeInterp``) and
``src/UsgsAstroLsSensorModel.cpp`` (``getImageTime``, ``computeDetectorView``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _lagrange(values, t0, dt, time, max_order, out):
    """usgscsm ``lagrangeInterp`` of the rows of ``values`` (n, k) at one time → out (k,)."""
    n = values.shape[0]
    k = values.shape[1]
    for c in range(k):
        out[c] = 0.0
    if n == 1:
        for c in range(k):
            out[c] = values[0, c]
        return
    fndex = (time - t0) / dt
    index = int(math.trunc(fndex))
    if index < 0:
        index = 0
    if index > n - 2:
        index = n - 2
    order = 2
    if 1 <= index < n - 2:
        order = 4
    if 2 <= index < n - 3:
        order = 6
    if 3 <= index < n - 4:
        order = 8
    if order > max_order:
        order = max_order
    tau = fndex - index
    shift = order // 2 - 1
    first = index - shift
    # Weights as demtool.sensors.base._lagrange_weights computes them (prefix and suffix
    # products of τ − x_m over integer denominators), so both paths round alike.
    factors = np.empty(order)
    for m in range(order):
        factors[m] = tau - (m - shift)
    for j in range(order):
        left = 1.0
        for m in range(j):
            left *= factors[m]
        right = 1.0
        for m in range(order - 1, j, -1):
            right *= factors[m]
        denominator = 1
        for m in range(order):
            if m != j:
                denominator *= j - m
        weight = left * right / denominator
        for c in range(k):
            out[c] += weight * values[first + j, c]


@njit(cache=True)
def _line_time(line, int_lines, int_starts, int_times):
    index = np.searchsorted(int_lines, line, side="right") - 1
    if index < 0:
        index = 0
    return int_starts[index] + int_times[index] * (line - int_lines[index] + 0.5)


@njit(cache=True)
def _pose(time, positions, t0_ephem, dt_ephem, quaternions, t0_quat, dt_quat, quat_order,
          pos, rot):
    """Sensor position (3,) and sensor-to-body rotation (3, 3) at one time, in place.

    The quaternion is Lagrange-interpolated, normalised and turned into the active
    rotation of ``demtool.sensors.base.quaternion_to_matrix`` (scalar last).
    """
    q = np.empty(4)
    _lagrange(positions, t0_ephem, dt_ephem, time, 8, pos)
    _lagrange(quaternions, t0_quat, dt_quat, time, quat_order, q)
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    qx, qy, qz, qw = q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm
    rot[0, 0] = qx * qx - qy * qy - qz * qz + qw * qw
    rot[0, 1] = 2 * (qx * qy - qz * qw)
    rot[0, 2] = 2 * (qx * qz + qy * qw)
    rot[1, 0] = 2 * (qx * qy + qz * qw)
    rot[1, 1] = -qx * qx + qy * qy - qz * qz + qw * qw
    rot[1, 2] = 2 * (qy * qz - qx * qw)
    rot[2, 0] = 2 * (qx * qz - qy * qw)
    rot[2, 1] = 2 * (qy * qz + qx * qw)
    rot[2, 2] = -qx * qx - qy * qy + qz * qz + qw * qw


@njit(parallel=True, cache=True)
def detector_view(lines, xyz, int_lines, int_starts, int_times, positions, t0_ephem,
                  dt_ephem, quaternions, t0_quat, dt_quat, quat_order, focal_length):
    """Undistorted focal-plane coordinates of ground points seen from image lines.

    Parameters
    ----------
    lines : (N,) float64
        Image lines (CSM convention) whose exposure looks at the points.
    xyz : (N, 3) float64
        Body-fixed ground points, metres.
    int_lines, int_starts, int_times : (K,) float64
        The line-scan-rate table sorted by line (line, start time, seconds per line).
    positions : (n, 3) float64
        Sensor positions (body-fixed metres) at ``t0_ephem + i dt_ephem``.
    quaternions : (m, 4) float64
        Sensor-to-body quaternions, scalar last, at ``t0_quat + j dt_quat``.
    quat_order : int
        Highest Lagrange order for the quaternions (8, or 4 for short tables).
    focal_length : float
        Millimetres.

    Returns
    -------
    x, y : (N,) float64
        Undistorted focal-plane coordinates, mm (``f · c_xy / c_z`` of the camera-frame
        vector ``c = Rᵀ (X − C)``).
    depth : (N,) float64
        ``c_z`` signed so that it is positive for points on the body's side of the
        focal plane (see ``LineScanSensor.image_to_ray``).
    """
    n = lines.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    depth = np.empty(n)
    for i in prange(n):
        line = lines[i]
        if not math.isfinite(line):
            x[i] = np.nan
            y[i] = np.nan
            depth[i] = np.nan
            continue
        time = _line_time(line, int_lines, int_starts, int_times)
        pos = np.empty(3)
        rot = np.empty((3, 3))
        _pose(time, positions, t0_ephem, dt_ephem, quaternions, t0_quat, dt_quat,
              quat_order, pos, rot)
        r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
        r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
        r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
        dx = xyz[i, 0] - pos[0]
        dy = xyz[i, 1] - pos[1]
        dz = xyz[i, 2] - pos[2]
        cx = r00 * dx + r10 * dy + r20 * dz
        cy = r01 * dx + r11 * dy + r21 * dz
        cz = r02 * dx + r12 * dy + r22 * dz
        toward = -1.0 if r02 * pos[0] + r12 * pos[1] + r22 * pos[2] > 0 else 1.0
        scale = focal_length / cz if cz != 0.0 else np.nan
        x[i] = cx * scale
        y[i] = cy * scale
        depth[i] = toward * cz
    return x, y, depth


@njit(parallel=True, cache=True)
def image_rays(lines, u, v, int_lines, int_starts, int_times, positions, t0_ephem, dt_ephem,
               quaternions, t0_quat, dt_quat, quat_order, focal_length):
    """Imaging rays of image lines and undistorted focal-plane points (``image_to_ray``).

    Parameters
    ----------
    lines : (N,) float64
        Image lines (CSM convention).
    u, v : (N,) float64
        Undistorted focal-plane coordinates of the samples, mm.
    int_lines, int_starts, int_times, positions, t0_ephem, dt_ephem, quaternions,
    t0_quat, dt_quat, quat_order, focal_length
        As :func:`detector_view`.

    Returns
    -------
    origin : (N, 3) float64
        Sensor positions at the lines' exposures, body-fixed metres.
    direction : (N, 3) float64
        Unit look vectors ``R (−u, −v, −f)``, body-fixed, turned toward the body (the
        sign rule of ``LineScanSensor.image_to_ray``); NaN where the line is not finite.
    """
    n = lines.shape[0]
    origin = np.empty((n, 3))
    direction = np.empty((n, 3))
    for i in prange(n):
        line = lines[i]
        if not math.isfinite(line):
            for c in range(3):
                origin[i, c] = np.nan
                direction[i, c] = np.nan
            continue
        time = _line_time(line, int_lines, int_starts, int_times)
        pos = np.empty(3)
        rot = np.empty((3, 3))
        _pose(time, positions, t0_ephem, dt_ephem, quaternions, t0_quat, dt_quat,
              quat_order, pos, rot)
        lx, ly, lz = -u[i], -v[i], -focal_length
        look0 = rot[0, 0] * lx + rot[0, 1] * ly + rot[0, 2] * lz
        look1 = rot[1, 0] * lx + rot[1, 1] * ly + rot[1, 2] * lz
        look2 = rot[2, 0] * lx + rot[2, 1] * ly + rot[2, 2] * lz
        sign = -1.0 if look0 * pos[0] + look1 * pos[1] + look2 * pos[2] > 0 else 1.0
        scale = sign / math.sqrt(look0 * look0 + look1 * look1 + look2 * look2)
        origin[i, 0], origin[i, 1], origin[i, 2] = pos[0], pos[1], pos[2]
        direction[i, 0] = look0 * scale
        direction[i, 1] = look1 * scale
        direction[i, 2] = look2 * scale
    return origin, direction
