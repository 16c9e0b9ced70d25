"""Compiled kernels of the line-scan model: exposure pose and projection per point.

:func:`detector_view` is the hot part of line-scan ground → image (each iteration of
the line search evaluates it once per point): the exposure time of an image line,
the sensor position and the sensor-to-body quaternion at that time by usgscsm's
Lagrange interpolation, and the projection of a ground point onto the undistorted
focal plane.  It computes exactly what :meth:`LineScanSensor.line_time`,
:meth:`~LineScanSensor.position_at`, :meth:`~LineScanSensor.rotation_at` and
:meth:`~LineScanSensor._detector_view` compute with numpy (up to rounding), the points in parts
on the calling thread and its helpers (:func:`demtool.tiling.rows.on_row_parts`).

Reference: DOI-USGS/usgscsm ``src/Utilities.cpp`` (``lagrangeInterp``) and
``src/UsgsAstroLsSensorModel.cpp`` (``getImageTime``, ``computeDetectorView``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _lagrange_setup(n, t0, dt, time, max_order):
    """usgscsm ``lagrangeInterp``'s choice at one time for n equally spaced samples:
    (first sample, order, τ, shift); one sample gives order 1 (the sample itself)."""
    if n == 1:
        return 0, 1, 0.0, 0
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
    shift = order // 2 - 1
    return index - shift, order, fndex - index, shift


@njit(cache=True)
def _lagrange_weight(j, order, tau, shift):
    """Weight of the j-th node, computed as demtool.sensors.base._lagrange_weights does
    (prefix and suffix products of τ − x_m over an integer denominator), so the compiled
    and numpy paths round alike."""
    left = 1.0
    for m in range(j):
        left *= tau - (m - shift)
    right = 1.0
    for m in range(order - 1, j, -1):
        right *= tau - (m - shift)
    denominator = 1
    for m in range(order):
        if m != j:
            denominator *= j - m
    return left * right / denominator


@njit(cache=True)
def _line_time(line, int_lines, int_starts, int_times):
    index = np.searchsorted(int_lines, line, side="right") - 1
    if index < 0:
        index = 0
    return int_starts[index] + int_times[index] * (line - int_lines[index] + 0.5)


@njit(cache=True)
def _pose(time, positions, t0_ephem, dt_ephem, quaternions, t0_quat, dt_quat, quat_order):
    """Sensor position and sensor-to-body rotation at one time, as 12 scalars
    ``(px, py, pz, r00, r01, r02, r10, r11, r12, r20, r21, r22)`` (no heap allocation).

    The position and the quaternion are Lagrange-interpolated (usgscsm
    ``lagrangeInterp``, order ≤ 8 and ≤ ``quat_order``); the quaternion is normalised
    and turned into the active rotation of ``demtool.sensors.base.quaternion_to_matrix``
    (scalar last).
    """
    first, order, tau, shift = _lagrange_setup(positions.shape[0], t0_ephem, dt_ephem,
                                               time, 8)
    px = 0.0
    py = 0.0
    pz = 0.0
    for j in range(order):
        w = _lagrange_weight(j, order, tau, shift)
        px += w * positions[first + j, 0]
        py += w * positions[first + j, 1]
        pz += w * positions[first + j, 2]
    first, order, tau, shift = _lagrange_setup(quaternions.shape[0], t0_quat, dt_quat,
                                               time, quat_order)
    qx = 0.0
    qy = 0.0
    qz = 0.0
    qw = 0.0
    for j in range(order):
        w = _lagrange_weight(j, order, tau, shift)
        qx += w * quaternions[first + j, 0]
        qy += w * quaternions[first + j, 1]
        qz += w * quaternions[first + j, 2]
        qw += w * quaternions[first + j, 3]
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
    return (px, py, pz,
            qx * qx - qy * qy - qz * qz + qw * qw, 2 * (qx * qy - qz * qw),
            2 * (qx * qz + qy * qw),
            2 * (qx * qy + qz * qw), -qx * qx + qy * qy - qz * qz + qw * qw,
            2 * (qy * qz - qx * qw),
            2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw),
            -qx * qx - qy * qy + qz * qz + qw * qw)


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
    from demtool.tiling.rows import on_row_parts

    n = lines.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    depth = np.empty(n)
    on_row_parts(lambda start, stop: _detector_view_rows(
        lines, xyz, int_lines, int_starts, int_times, positions, t0_ephem, dt_ephem,
        quaternions, t0_quat, dt_quat, quat_order, focal_length, x, y, depth, start, stop),
        n)
    return x, y, depth


@njit(cache=True, nogil=True, error_model="numpy")
def _detector_view_rows(lines, xyz, int_lines, int_starts, int_times, positions, t0_ephem,
                        dt_ephem, quaternions, t0_quat, dt_quat, quat_order, focal_length,
                        x, y, depth, start, stop):
    """:func:`detector_view` of points ``start … stop − 1`` into ``x``, ``y``, ``depth``
    (run over row parts by :func:`demtool.tiling.rows.on_row_parts`: a serial ``nogil``
    kernel compiles in a fraction of a ``parallel=True`` one's time)."""
    for i in range(start, stop):
        line = lines[i]
        if not math.isfinite(line):
            x[i] = np.nan
            y[i] = np.nan
            depth[i] = np.nan
            continue
        time = _line_time(line, int_lines, int_starts, int_times)
        p0, p1, p2, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _pose(
            time, positions, t0_ephem, dt_ephem, quaternions, t0_quat, dt_quat, quat_order)
        dx = xyz[i, 0] - p0
        dy = xyz[i, 1] - p1
        dz = xyz[i, 2] - p2
        cx = r00 * dx + r10 * dy + r20 * dz
        cy = r01 * dx + r11 * dy + r21 * dz
        cz = r02 * dx + r12 * dy + r22 * dz
        toward = -1.0 if r02 * p0 + r12 * p1 + r22 * p2 > 0 else 1.0
        scale = focal_length / cz if cz != 0.0 else np.nan
        x[i] = cx * scale
        y[i] = cy * scale
        depth[i] = toward * cz


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
    from demtool.tiling.rows import on_row_parts

    n = lines.shape[0]
    origin = np.empty((n, 3))
    direction = np.empty((n, 3))
    on_row_parts(lambda start, stop: _image_rays_rows(
        lines, u, v, int_lines, int_starts, int_times, positions, t0_ephem, dt_ephem,
        quaternions, t0_quat, dt_quat, quat_order, focal_length, origin, direction, start,
        stop), n)
    return origin, direction


@njit(cache=True, nogil=True, error_model="numpy")
def _image_rays_rows(lines, u, v, int_lines, int_starts, int_times, positions, t0_ephem,
                     dt_ephem, quaternions, t0_quat, dt_quat, quat_order, focal_length,
                     origin, direction, start, stop):
    """:func:`image_rays` of points ``start … stop − 1`` into ``origin``, ``direction``."""
    for i in range(start, stop):
        line = lines[i]
        if not math.isfinite(line):
            for c in range(3):
                origin[i, c] = np.nan
                direction[i, c] = np.nan
            continue
        time = _line_time(line, int_lines, int_starts, int_times)
        p0, p1, p2, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _pose(
            time, positions, t0_ephem, dt_ephem, quaternions, t0_quat, dt_quat, quat_order)
        lx, ly, lz = -u[i], -v[i], -focal_length
        look0 = r00 * lx + r01 * ly + r02 * lz
        look1 = r10 * lx + r11 * ly + r12 * lz
        look2 = r20 * lx + r21 * ly + r22 * lz
        sign = -1.0 if look0 * p0 + look1 * p1 + look2 * p2 > 0 else 1.0
        scale = sign / math.sqrt(look0 * look0 + look1 * look1 + look2 * look2)
        origin[i, 0], origin[i, 1], origin[i, 2] = p0, p1, p2
        direction[i, 0] = look0 * scale
        direction[i, 1] = look1 * scale
        direction[i, 2] = look2 * scale
