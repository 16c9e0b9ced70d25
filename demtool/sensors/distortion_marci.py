"""The lens distortion of MRO MARCI, which usgscsm has no model for, read from cubes
(registered in :mod:`demtool.sensors.distortion` under the name below).

==========  ==========================================================================
model       coefficients and definition (``remove``: distorted → undistorted, mm)
==========  ==========================================================================
``marci``   ``[p, k0, k1, k2, k3]``: ISIS ``MarciDistortionMap``: in pixels of pitch
            ``p`` mm, ``u = d (k0 + k1 r² + k2 r⁴ + k3 r⁶)``, ``r = |d| / p``
            (``INS<code>_DISTORTION_COEFFS``, ``INS<code>_PIXEL_SIZE``)
==========  ==========================================================================

``apply`` (undistorted → distorted) solves the radial equation by Newton–Raphson to
1e-12 pixel, as ISIS's ``SetUndistortedFocalPlane`` does to 1e-9 (ISIS starts from a
per-filter guess; the converged root is the same); points that do not converge are NaN.

Reference: DOI-USGS/ISIS3 ``isis/src/mro/objs/MarciCamera/MarciDistortionMap.cpp``.
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


#: Coefficient counts, apply and remove functions of the models above.
COUNTS = {"marci": (5,)}
APPLY = {"marci": _marci_apply}
REMOVE = {"marci": _marci_remove}
