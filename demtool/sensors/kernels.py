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
    for j in range(order):
        weight = 1.0
        for m in range(order):
            if m != j:
                weight *= (tau - (m - shift)) / (j - m)
        for c in range(k):
            out[c] += weight * values[first + j, c]


@njit(cache=True)
def _line_time(line, int_lines, int_starts, int_times):
    index = np.searchsorted(int_lines, line, side="right") - 1
    if index < 0:
        index = 0
    return int_starts[index] + int_times[index] * (line - int_lines[index] + 0.5)


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
        q = np.empty(4)
        _lagrange(positions, t0_ephem, dt_ephem, time, 8, pos)
        _lagrange(quaternions, t0_quat, dt_quat, time, quat_order, q)
        norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        qx, qy, qz, qw = q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm
        # Columns of the sensor-to-body rotation (quaternion_to_matrix).
        r00 = qx * qx - qy * qy - qz * qz + qw * qw
        r10 = 2 * (qx * qy + qz * qw)
        r20 = 2 * (qx * qz - qy * qw)
        r01 = 2 * (qx * qy - qz * qw)
        r11 = -qx * qx + qy * qy - qz * qz + qw * qw
        r21 = 2 * (qy * qz + qx * qw)
        r02 = 2 * (qx * qz + qy * qw)
        r12 = 2 * (qy * qz - qx * qw)
        r22 = -qx * qx - qy * qy + qz * qz + qw * qw
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
