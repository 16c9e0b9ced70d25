"""Lens distortions of ISIS cameras that usgscsm has no model for, read from cubes
(registered in :mod:`demtool.sensors.distortion` under the names below).

==========  ==========================================================================
model       coefficients and definition (``remove``: distorted → undistorted, mm)
==========  ==========================================================================
``marci``   ``[p, k0, k1, k2, k3]``: ISIS ``MarciDistortionMap``: in pixels of pitch
            ``p`` mm, ``u = d (k0 + k1 r² + k2 r⁴ + k3 r⁶)``, ``r = |d| / p``
            (``INS<code>_DISTORTION_COEFFS``, ``INS<code>_PIXEL_SIZE``)
``lrowac``  ``[k1, k2, k3]``: ISIS ``LroWideAngleCameraDistortionMap``:
            ``u = d (1 + k1 r² + k2 r⁴ + k3 r⁶)`` (mm; the filter's ``INS<code>_OD_K``)
``cassis``  ``[hx, hy, A1(6), A2(6), A3(6)]``: ISIS ``TgoCassisDistortionMap`` (CaSSIS): with
            ``χ = (x², xy, y², x, y, 1)`` (mm), ``u = (A1·χ, A2·χ) / A3·χ`` (the IK's
            ``_OD_A1/2/3_CORR``) on the CCD, ``|x| ≤ hx + 0.2``, ``|y| ≤ hy + 0.2``
            (``hx, hy`` half the CCD in mm: pitch × ``FILTER_SAMPLES/LINES`` / 2), the
            identity off it
``mocwa``   ``[s, c0, …, c5]``: ISIS ``MocWideAngleDistortionMap``, focal length ``f``
            (the model's): ``y' = y / s``, field angle ``θ = atan(|(x, y')| / f)``,
            ``θ_u = θ (c0 + c1 θ² + … + c5 θ¹⁰)``, ``u = (x, y') f tan θ_u / |(x, y')|``
            (ISIS's constants: red ``s`` 1, blue 1.000452)
==========  ==========================================================================

``lrowac`` is ``marci`` with a pitch of 1 mm and ``k0 = 1``.  ``cassis``'s ``apply``
inverts ``remove`` by Newton–Raphson (to 1e-12 mm): ISIS's ``SetUndistortedFocalPlane``
evaluates a second, separately fitted rational model (``_OD_A*_DIST``), which inverts
the correction only to its fit.  ``marci``'s ``apply``
(undistorted → distorted) solves the radial equation by
Newton–Raphson to 1e-12 pixel, as ISIS's ``SetUndistortedFocalPlane`` does to 1e-9
(ISIS starts from a per-filter guess; the converged root is the same); points that do
not converge are NaN.  ``mocwa``'s ``apply`` inverts ``remove`` by Newton–Raphson on
the field angle (to 1e-14 rad): ISIS's ``SetUndistortedFocalPlane`` uses a second,
fitted polynomial instead, which inverts ``remove`` only to its fit (a round trip
through ISIS's two maps moves a point), so that one is not used.

References: DOI-USGS/ISIS3 ``isis/src/mro/objs/MarciCamera/MarciDistortionMap.cpp``,
``isis/src/mgs/objs/MocWideAngleCamera/MocWideAngleDistortionMap.cpp``,
``isis/src/lro/objs/LroWideAngleCamera/LroWideAngleCameraDistortionMap.cpp``,
``isis/src/tgo/objs/TgoCassisCamera/TgoCassisDistortionMap.cpp``.
"""

from __future__ import annotations

import numpy as np


def _marci_factor(rr, c):
    return c[1] + rr * (c[2] + rr * (c[3] + rr * c[4]))


def _marci_remove(x, y, c, f, tol):
    p = c[0]
    rr = (x * x + y * y) / (p * p)
    factor = _marci_factor(rr, c)
    return x * factor, y * factor


def _marci_apply(x, y, c, f, tol):
    p = c[0]
    ru = np.hypot(x, y) / p
    rd = ru / c[1]
    with np.errstate(all="ignore"):
        for _ in range(50):
            rr = rd * rd
            g = rd * _marci_factor(rr, c) - ru
            dg = c[1] + rr * (3 * c[2] + rr * (5 * c[3] + rr * 7 * c[4]))
            step = g / dg
            rd = rd - step
            if np.all(~(np.abs(step) > 1e-12)):
                break
        scale = np.where(ru > 0, rd / np.where(ru > 0, ru, 1.0), 1.0 / c[1])
        scale = np.where(np.abs(step) > 1e-9, np.nan, scale)
    return x * scale, y * scale


def _moc_angle(theta, c):
    t2 = theta * theta
    poly = c[6]
    for k in (5, 4, 3, 2, 1):
        poly = poly * t2 + c[k]
    return theta * poly


def _mocwa_remove(x, y, c, f, tol):
    sy = y / c[0]
    s = np.hypot(x, sy)
    with np.errstate(all="ignore"):
        sp = f * np.tan(_moc_angle(np.arctan(s / f), c))
        ratio = np.where(s > 0, sp / np.where(s > 0, s, 1.0), c[1])
    return x * ratio, sy * ratio


def _mocwa_apply(x, y, c, f, tol):
    sp = np.hypot(x, y)
    target = np.arctan(sp / f)
    theta = target / c[1]
    with np.errstate(all="ignore"):
        for _ in range(50):
            t2 = theta * theta
            slope = 11 * c[6]
            for k in (5, 4, 3, 2, 1):
                slope = slope * t2 + (2 * k - 1) * c[k]
            step = (_moc_angle(theta, c) - target) / slope
            theta = theta - step
            if np.all(~(np.abs(step) > 1e-14)):
                break
        theta = np.where(np.abs(step) > 1e-10, np.nan, theta)
        ratio = np.where(sp > 0, f * np.tan(theta) / np.where(sp > 0, sp, 1.0), 1.0 / c[1])
    return x * ratio, y * ratio * c[0]


def _lrowac_remove(x, y, c, f, tol):
    return _marci_remove(x, y, [1.0, 1.0, *c], f, tol)


def _lrowac_apply(x, y, c, f, tol):
    return _marci_apply(x, y, [1.0, 1.0, *c], f, tol)


def _chi_dot(x, y, a):
    return a[0] * x * x + a[1] * x * y + a[2] * y * y + a[3] * x + a[4] * y + a[5]


def _cassis_on_ccd(x, y, c):
    return (np.abs(x) <= c[0] + 0.2) & (np.abs(y) <= c[1] + 0.2)


def _cassis_remove(x, y, c, f, tol):
    a1, a2, a3 = c[2:8], c[8:14], c[14:20]
    with np.errstate(all="ignore"):
        divider = _chi_dot(x, y, a3)
        ux, uy = _chi_dot(x, y, a1) / divider, _chi_dot(x, y, a2) / divider
    on = _cassis_on_ccd(x, y, c)
    return np.where(on, ux, x), np.where(on, uy, y)


def _cassis_apply(x, y, c, f, tol):
    a1, a2, a3 = c[2:8], c[8:14], c[14:20]
    dx, dy = np.array(x, dtype=np.float64), np.array(y, dtype=np.float64)
    with np.errstate(all="ignore"):
        for _ in range(50):
            q = _chi_dot(dx, dy, a3)
            p1, p2 = _chi_dot(dx, dy, a1), _chi_dot(dx, dy, a2)
            fx, fy = p1 / q - x, p2 / q - y
            # ∂(A·χ)/∂x = 2 a0 x + a1 y + a3, ∂/∂y = a1 x + 2 a2 y + a4
            qx, qy = 2 * a3[0] * dx + a3[1] * dy + a3[3], a3[1] * dx + 2 * a3[2] * dy + a3[4]
            j11 = ((2 * a1[0] * dx + a1[1] * dy + a1[3]) * q - p1 * qx) / (q * q)
            j12 = ((a1[1] * dx + 2 * a1[2] * dy + a1[4]) * q - p1 * qy) / (q * q)
            j21 = ((2 * a2[0] * dx + a2[1] * dy + a2[3]) * q - p2 * qx) / (q * q)
            j22 = ((a2[1] * dx + 2 * a2[2] * dy + a2[4]) * q - p2 * qy) / (q * q)
            det = j11 * j22 - j12 * j21
            sx, sy = (j22 * fx - j12 * fy) / det, (-j21 * fx + j11 * fy) / det
            dx, dy = dx - sx, dy - sy
            if np.all(~(np.abs(sx) > 1e-12) & ~(np.abs(sy) > 1e-12)):
                break
        bad = (np.abs(sx) > 1e-9) | (np.abs(sy) > 1e-9)
    on = _cassis_on_ccd(dx, dy, c)
    dx, dy = np.where(on, dx, x), np.where(on, dy, y)
    return np.where(bad & on, np.nan, dx), np.where(bad & on, np.nan, dy)


#: Coefficient counts, apply and remove functions of the models above.
COUNTS = {"marci": (5,), "mocwa": (7,), "lrowac": (3,), "cassis": (20,)}
APPLY = {"marci": _marci_apply, "mocwa": _mocwa_apply, "lrowac": _lrowac_apply,
         "cassis": _cassis_apply}
REMOVE = {"marci": _marci_remove, "mocwa": _mocwa_remove, "lrowac": _lrowac_remove,
          "cassis": _cassis_remove}
