"""ISIS mission distortion maps that ALE writes into ISDs but usgscsm does not implement,
applied from their ISIS definitions (:class:`demtool.sensors.distortion.Distortion`
dispatches to them; same signature as the CSM models: focal-plane mm in, mm out).

``legendre``  New Horizons Ralph MVIC in framing mode
              (``NewHorizonsMvicFrameCameraDistortionMap``): coefficients
              ``[half_x, half_y, x0 … x19, y0 … y19]`` — the focal plane's half-width and
              half-height in mm (ISIS: ½ · samples · pixel pitch, ½ · lines · pitch) and
              ALE's ``x_coefficients`` / ``y_coefficients`` (the IK's
              ``INS-98900_DISTORTION_COEF_X/_Y``).  Coordinates are negated and scaled to
              [−1, 1], the correction is a sum of products of Legendre polynomials
              ``P_i(x) P_j(y)`` of total degree 1 … 5 (ISIS's term order), added to the
              scaled distorted point (distorted → undistorted); points off the detector
              are left as they are.  Undistorted → distorted iterates ``t ← u − δ(t)``
              (ISIS: tolerance 1e-6 in scaled units, 50 passes).
``themisir``  Mars Odyssey THEMIS IR (``ThemisIrDistortionMap``): ``[alpha1, alpha2, k]``
              (ALE's ``p_alpha1``, ``p_alpha2``, ``p_k``, the band's k):
              ``x_d = k x_u``, ``y_d = y_u (1 + α1) + α2 y_u²``, inverted in closed form
              (``y_u = 2 y_d / (1 + α1 + √((1 + α1)² + 4 α2 y_d))``).

References: DOI-USGS/ISIS3 ``isis/src/newhorizons/objs/NewHorizonsMvicFrameCamera/
NewHorizonsMvicFrameCameraDistortionMap.cpp`` and ``isis/src/odyssey/objs/ThemisIrCamera/
ThemisIrDistortionMap.cpp``.
"""

from __future__ import annotations

import numpy as np

#: (i, j) of the term ``P_i(x) P_j(y)`` multiplying each of the 20 coefficients (ISIS).
LEGENDRE_TERMS = ((0, 1), (1, 0), (0, 2), (1, 1), (2, 0), (0, 3), (1, 2), (2, 1), (3, 0),
                  (0, 4), (1, 3), (2, 2), (3, 1), (4, 0), (0, 5), (1, 4), (2, 3), (3, 2),
                  (4, 1), (5, 0))


def _legendre_polys(t) -> list:
    """P_0 … P_5 at ``t`` (Bonnet's recursion)."""
    p = [np.ones_like(t), t]
    for n in range(1, 5):
        p.append(((2 * n + 1) * t * p[n] - n * p[n - 1]) / (n + 1))
    return p


def _legendre_delta(xs, ys, c):
    px, py = _legendre_polys(xs), _legendre_polys(ys)
    dx = np.zeros_like(xs)
    dy = np.zeros_like(xs)
    for k, (i, j) in enumerate(LEGENDRE_TERMS):
        term = px[i] * py[j]
        dx = dx + c[2 + k] * term
        dy = dy + c[22 + k] * term
    return dx, dy


def legendre_remove(x, y, c, f, tol):
    """Distorted → undistorted focal plane (mm), ISIS ``SetFocalPlane``."""
    hx, hy = c[0], c[1]
    xs, ys = -x / hx, -y / hy
    on = (np.abs(x) <= hx) & (np.abs(y) <= hy)
    dx, dy = _legendre_delta(xs, ys, c)
    return np.where(on, -(xs + dx) * hx, x), np.where(on, -(ys + dy) * hy, y)


def legendre_apply(x, y, c, f, tol):
    """Undistorted → distorted (mm): the inverse of :func:`legendre_remove` by the
    fixed-point iteration of ISIS ``SetUndistortedFocalPlane`` (NaN where it does not
    converge); off the detector the point is kept, as ``remove`` keeps it."""
    hx, hy = c[0], c[1]
    us, vs = -x / hx, -y / hy
    ts, ss = us.copy(), vs.copy()
    active = np.ones(np.shape(us), dtype=bool)
    for _ in range(50):
        dx, dy = _legendre_delta(ts, ss, c)
        nx, ny = us - dx, vs - dy
        moved = (np.abs(nx - ts) > 1e-12) | (np.abs(ny - ss) > 1e-12)
        ts, ss = np.where(active, nx, ts), np.where(active, ny, ss)
        active &= moved
        if not active.any():
            break
    dist_x, dist_y = -ts * hx, -ss * hy
    on = (np.abs(dist_x) <= hx) & (np.abs(dist_y) <= hy)
    dist_x = np.where(active, np.nan, np.where(on, dist_x, x))
    dist_y = np.where(active, np.nan, np.where(on, dist_y, y))
    return dist_x, dist_y


def themisir_remove(x, y, c, f, tol):
    """Distorted → undistorted (mm), ISIS ``ThemisIrDistortionMap::SetFocalPlane``."""
    a1, a2, k = c
    with np.errstate(invalid="ignore", divide="ignore"):
        radical = np.sqrt((1.0 + a1) ** 2 + 4.0 * a2 * y)
        return x / k, 2.0 * y / (1.0 + a1 + radical)


def themisir_apply(x, y, c, f, tol):
    """Undistorted → distorted (mm), ISIS ``SetUndistortedFocalPlane``."""
    a1, a2, k = c
    return x * k, y + a1 * y + a2 * y * y
