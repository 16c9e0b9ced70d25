"""Lens distortion models of the USGS Community Sensor Model, and OpenCV's Brown model.

Every model maps between *undistorted* and *distorted* focal-plane coordinates
``(x, y)``, in the focal plane's own unit (millimetres for the CSM models, normalised
image coordinates ``x/z, y/z`` for :data:`BROWN`).  ``apply`` goes undistorted →
distorted (used by ground → image), ``remove`` goes distorted → undistorted (image →
ground).  Both are vectorised over arrays of any shape and never modify their inputs.

The formulas, iteration counts and tolerances follow usgscsm's ``src/Distortion.cpp``
(DOI-USGS/usgscsm, ``applyDistortion`` / ``removeDistortion``), which itself ports the
ISIS distortion maps; the one deliberate difference is noted at :func:`_cahvor_apply`.
The Lunar Orbiter model follows ISIS's ``LoHighDistortionMap`` (perspective factor, then
radial distortion about a centre point).

Coefficient layouts (as ALE writes them into an ISD's ``optical_distortion``):

==============  ===============================================================
model           coefficients
==============  ===============================================================
``radial``      ``[k0, k1, k2]``: ``u = d (1 − (k0 + k1 r² + k2 r⁴))``
``transverse``  ``x[10] + y[10]``: cubic polynomials, distorted = P(undistorted)
``radtan``      ``[k1, k2, p1, p2, k3]`` on coordinates divided by the focal length
``lrolrocnac``  ``[k1]``: ``u_y = d_y / (1 + k1 d_y²)``
``dawnfc``      ``[k]``: ``d = u (1 + k r_u²)``
``kaguyalism``  ``[bx, a0..a3, by, b0..b3]``: ``u = d + bore + a(r)``
``cahvor``      ``[k0, k1, k2, x0, y0]``: radial about the centre ``(x0, y0)``
``lunarorbiter``  ``[perspective_x, perspective_y, center_x, center_y, k0, k1]``
``brown``       ``[k1, k2, p1, p2, k3]`` (OpenCV), on normalised coordinates
``brownconrady``  ``[xp, yp, k1, k2, k3, p1, p2, phi]`` (ASP / VisionWorkbench),
                ``remove`` in closed form, on normalised coordinates
``photometrix``  ``[xp, yp, k1, k2, k3, p1, p2]`` (ASP / VisionWorkbench), likewise
``apollometric``  ``[xp, yp, k1, k2, k3, j1, j2, t0]`` (ISIS ``ApolloMetricDistortionMap``;
                the NAIF IK's ``INS-91x240_PP``, ``_OD_K``, ``_DECENTER``), in mm
``legendre``    ``[half_x, half_y, x0..x19, y0..y19]`` (ISIS, New Horizons MVIC frames)
``themisir``    ``[alpha1, alpha2, k]`` (ISIS, Mars Odyssey THEMIS IR); both in
                :mod:`demtool.sensors.distortion_isis`
``opencv``      ``[k1, k2, k3, k4, k5, k6, p1, p2, sx, sy, ox, oy]`` (ISIS
                ``OsirisRexTagcamsDistortionMap``: OpenCV's rational radial and
                tangential model on ``(u/f, −v/f)``; ``sx, sy`` the model's focal
                lengths over the camera's, ``ox, oy`` the focal-plane mm of its centre)
==============  ===============================================================

The two ASP models are defined from distorted to undistorted coordinates in the
pinhole's physical focal-plane units; :func:`demtool.sensors.tsai.read_tsai` rescales
their coefficients to normalised coordinates (exact when ``fu = fv``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MODELS = ("none", "radial", "transverse", "radtan", "lrolrocnac", "dawnfc", "kaguyalism",
          "cahvor", "lunarorbiter", "brown", "brownconrady", "photometrix", "apollometric",
          "opencv")
NONE = "none"
BROWN = "brown"
_COUNTS = {"radial": (3,), "transverse": (20,), "radtan": (5,), "lrolrocnac": (1,),
           "dawnfc": (1,), "kaguyalism": (10,), "cahvor": (5,), "lunarorbiter": (6,),
           "brown": (4, 5, 8), "brownconrady": (8,), "photometrix": (7,), "apollometric": (8,),
           "opencv": (12,), "none": (0,)}


@dataclass(frozen=True)
class Distortion:
    """A lens distortion model and its coefficients.

    Attributes
    ----------
    model : str
        One of :data:`MODELS`.
    coefficients : (K,) float64
        The model's coefficients (layouts in the module docstring).
    focal_length : float
        Focal length in focal-plane units; only ``radtan`` uses it (it normalises
        coordinates by it, as usgscsm does).
    """

    model: str = NONE
    coefficients: np.ndarray = field(default_factory=lambda: np.zeros(0))
    focal_length: float = 1.0

    def __post_init__(self) -> None:
        model = str(self.model).lower()
        if model not in MODELS:
            raise ValueError(f"unknown distortion model {self.model!r}; known: "
                             f"{', '.join(MODELS)}")
        coefficients = np.asarray(self.coefficients, dtype=np.float64).reshape(-1)
        if model == BROWN and len(coefficients) == 4:
            coefficients = np.append(coefficients, 0.0)
        if len(coefficients) not in _COUNTS[model]:
            raise ValueError(f"distortion model {model!r} takes {_COUNTS[model]} "
                             f"coefficients, got {len(coefficients)}")
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "coefficients", coefficients)
        object.__setattr__(self, "focal_length", float(self.focal_length))

    @property
    def is_identity(self) -> bool:
        """True when the model leaves every point where it is."""
        return self.model == NONE or not np.any(self.coefficients)

    def apply(self, x, y, *, tolerance: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted → distorted focal-plane coordinates (arrays of any shape)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.model == NONE:
            return x.copy(), y.copy()
        return _APPLY[self.model](x, y, self.coefficients, self.focal_length, tolerance)

    def remove(self, x, y, *, tolerance: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Distorted → undistorted focal-plane coordinates (arrays of any shape)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.model == NONE:
            return x.copy(), y.copy()
        return _REMOVE[self.model](x, y, self.coefficients, self.focal_length, tolerance)

    def as_dict(self) -> dict:
        """Plain form (for JSON and NPZ)."""
        return {"model": self.model, "coefficients": self.coefficients.tolist(),
                "focal_length": self.focal_length}


# ---------------------------------------------------------------------------------------
# radial (usgscsm RADIAL)
# ---------------------------------------------------------------------------------------

def _radial_factor(rr, c):
    return c[0] + rr * (c[1] + rr * c[2])


def _radial_remove(x, y, c, f, tol):
    dr = _radial_factor(x * x + y * y, c)
    return x * (1.0 - dr), y * (1.0 - dr)


def _radial_apply(x, y, c, f, tol, cx=0.0, cy=0.0):
    # Fixed-point iteration on the distorted radius r = rp + dr(r) r (usgscsm RADIAL).
    sx, sy = x - cx, y - cy
    rp = np.sqrt(sx * sx + sy * sy)
    dr_over_r = _radial_factor(rp * rp, c)
    r = rp + dr_over_r * rp
    active = np.ones(rp.shape, dtype=bool)
    with np.errstate(all="ignore"):  # diverging points are caught below
        for _ in range(20):
            r_prev = r
            dr_over_r = np.where(active, _radial_factor(r_prev * r_prev, c), dr_over_r)
            r = np.where(active, rp + dr_over_r * r_prev, r)
            active &= ~(np.abs(r - r_prev) <= tol)
            if not active.any():
                break
    failed = active | ~np.isfinite(r) | (np.abs(r) > 1e9)
    if np.any(failed):
        # Coefficients so large that the distorted radius lies beyond the turning point
        # of r (1 − D(r²)) (seen in ALE's MGS MOC test ISD): usgscsm gives up and
        # returns the undistorted point; here Newton's method on the far branch,
        # r (D(r²) − 1) = rp, started on its asymptote, finds the point remove() maps
        # back to ``(x, y)`` (d antiparallel to u).
        top = 2 if c[2] != 0 else 1
        with np.errstate(all="ignore"):
            rf = (rp[failed] / abs(c[top])) ** (1.0 / (2 * top + 1)) + 1e-3
            for _ in range(60):
                d = _radial_factor(rf * rf, c)
                dd = 2 * rf * (c[1] + 2 * c[2] * rf * rf)
                g = rf * (d - 1.0) - rp[failed]
                step = g / (d - 1.0 + rf * dd)
                rf = rf - step
                if not np.any(np.abs(step) > tol * 1e-3):
                    break
            dr_far = _radial_factor(rf * rf, c)
        dr_over_r = dr_over_r.copy() if dr_over_r.ndim else np.asarray(dr_over_r)
        dr_over_r[failed] = np.where(np.isfinite(dr_far) & (dr_far > 1.0), dr_far, 0.0)
    with np.errstate(all="ignore"):
        return sx / (1.0 - dr_over_r) + cx, sy / (1.0 - dr_over_r) + cy


# ---------------------------------------------------------------------------------------
# transverse (usgscsm TRANSVERSE): third-order polynomials, Newton–Raphson inverse
# ---------------------------------------------------------------------------------------

def _transverse_terms(x, y):
    return [np.ones_like(x), x, y, x * x, x * y, y * y, x * x * x, x * x * y, x * y * y,
            y * y * y]


def _transverse_apply(x, y, c, f, tol):
    terms = _transverse_terms(x, y)
    cx, cy = c[:10], c[10:]
    return _dot(terms, cx), _dot(terms, cy)


def _transverse_jacobian(x, y, c):
    zero, one = np.zeros_like(x), np.ones_like(x)
    d_dx = [zero, one, zero, 2 * x, y, zero, 3 * x * x, 2 * x * y, y * y, zero]
    d_dy = [zero, zero, one, zero, x, 2 * y, zero, x * x, 2 * x * y, 3 * y * y]
    cx, cy = c[:10], c[10:]
    return _dot(d_dx, cx), _dot(d_dy, cx), _dot(d_dx, cy), _dot(d_dy, cy)


def _dot(terms, coefficients):
    return sum(t * k for t, k in zip(terms, coefficients, strict=True))


def _newton(dx, dy, forward, jacobian, tol, max_iterations=20):
    """Solve forward(u) = d for u by Newton–Raphson, vectorised (usgscsm newtonRaphson)."""
    ux, uy = dx.copy(), dy.copy()
    for _ in range(max_iterations):
        fx, fy = forward(ux, uy)
        rx, ry = dx - fx, dy - fy
        if not np.any(np.abs(rx) + np.abs(ry) > tol):
            break
        jxx, jxy, jyx, jyy = jacobian(ux, uy)
        det = jxx * jyy - jxy * jyx
        ok = np.abs(det) > 1e-12
        safe = np.where(ok, det, 1.0)
        ux = np.where(ok, ux + (jyy * rx - jxy * ry) / safe, ux)
        uy = np.where(ok, uy + (jxx * ry - jyx * rx) / safe, uy)
    return ux, uy


def _transverse_remove(x, y, c, f, tol):
    return _newton(x, y, lambda u, v: _transverse_apply(u, v, c, f, tol),
                   lambda u, v: _transverse_jacobian(u, v, c), tol)


# ---------------------------------------------------------------------------------------
# radtan (usgscsm RADTAN) and OpenCV Brown: same polynomial, on normalised coordinates
# ---------------------------------------------------------------------------------------

def _brown_forward(x, y, c):
    k1, k2, p1, p2, k3 = c[:5]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def _brown_jacobian(x, y, c):
    k1, k2, p1, p2, k3 = c[:5]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    jxx = radial + x * dradial * 2 * x + 2 * p1 * y + 6 * p2 * x
    jxy = x * dradial * 2 * y + 2 * p1 * x + 2 * p2 * y
    jyx = y * dradial * 2 * x + 2 * p1 * x + 2 * p2 * y
    jyy = radial + y * dradial * 2 * y + 6 * p1 * y + 2 * p2 * x
    return jxx, jxy, jyx, jyy


def _brown_apply(x, y, c, f, tol):
    return _brown_forward(x, y, c)


def _brown_remove(x, y, c, f, tol):
    return _newton(x, y, lambda u, v: _brown_forward(u, v, c),
                   lambda u, v: _brown_jacobian(u, v, c), min(tol, 1e-12), 30)


def _radtan_apply(x, y, c, f, tol):
    dx, dy = _brown_forward(x / f, y / f, c)
    return dx * f, dy * f


def _radtan_remove(x, y, c, f, tol):
    ux, uy = _newton(x / f, y / f, lambda u, v: _brown_forward(u, v, c),
                     lambda u, v: _brown_jacobian(u, v, c), tol / f)
    return ux * f, uy * f


# ---------------------------------------------------------------------------------------
# LRO LROC NAC (ISIS LroNarrowAngleDistortionMap): distortion along detector y only
# ---------------------------------------------------------------------------------------

def _lroc_remove(x, y, c, f, tol):
    return x.copy(), y / (1.0 + c[0] * y * y)


def _lroc_apply(x, y, c, f, tol):
    yt = y.copy()
    for _ in range(50):
        previous = yt
        yt = y * (1.0 + c[0] * previous * previous)
        if not np.any(np.abs(yt - previous) > 1e-10):
            break
    yt = np.where(np.abs(y) > 40, y, yt)  # far off the detector: no root (usgscsm)
    return x.copy(), yt


# ---------------------------------------------------------------------------------------
# Dawn FC (ISIS DawnFcDistortionMap): distortion is the closed form direction
# ---------------------------------------------------------------------------------------

def _dawn_apply(x, y, c, f, tol):
    scale = 1.0 + c[0] * (x * x + y * y)
    return x * scale, y * scale


def _dawn_remove(x, y, c, f, tol):
    r2 = x * x + y * y
    ux, uy = x, y
    for _ in range(20):
        ux = x / (1.0 + c[0] * r2)
        uy = y / (1.0 + c[0] * r2)
        r2 = ux * ux + uy * uy
        gx, gy = ux * (1.0 + c[0] * r2), uy * (1.0 + c[0] * r2)
        if not np.any((np.abs(gx - x) >= tol) | (np.abs(gy - y) >= tol)):
            break
    return ux, uy


# ---------------------------------------------------------------------------------------
# Kaguya LISM (SEL_TC_V01.TI, SEL_MI_V01.TI)
# ---------------------------------------------------------------------------------------

def _kaguya_offsets(x, y, c):
    r2 = x * x + y * y
    r = np.sqrt(r2)
    ax, ay = c[1:5], c[6:10]
    return (ax[0] + ax[1] * r + ax[2] * r2 + ax[3] * r2 * r,
            ay[0] + ay[1] * r + ay[2] * r2 + ay[3] * r2 * r)


def _kaguya_remove(x, y, c, f, tol):
    ox, oy = _kaguya_offsets(x, y, c)
    return x + ox + c[0], y + oy + c[5]


def _kaguya_apply(x, y, c, f, tol):
    xt, yt = x - c[0], y - c[5]
    for _ in range(50):
        px, py = xt, yt
        ox, oy = _kaguya_offsets(px, py, c)
        xt, yt = x - ox - c[0], y - oy - c[5]
        if not np.any((np.abs(xt - px) >= 1e-6) | (np.abs(yt - py) >= 1e-6)):
            break
    return xt, yt


# ---------------------------------------------------------------------------------------
# CAHVOR (usgscsm CAHVOR): radial about an offset centre
# ---------------------------------------------------------------------------------------

def _cahvor_remove(x, y, c, f, tol):
    ux, uy = _radial_remove(x - c[3], y - c[4], c, f, tol)
    return ux + c[3], uy + c[4]


def _cahvor_apply(x, y, c, f, tol):
    """Inverse of :func:`_cahvor_remove`.

    usgscsm (2.0) seeds this iteration with the radius about the focal-plane origin
    instead of about ``(x0, y0)`` ("untested manually"), so its apply is not the exact
    inverse of its remove; here both use the radius about the centre, so that
    ``apply(remove(p)) == p``.
    """
    return _radial_apply(x, y, c, f, tol, c[3], c[4])


# ---------------------------------------------------------------------------------------
# Lunar Orbiter high/medium resolution cameras (ISIS LoHighDistortionMap)
# ---------------------------------------------------------------------------------------

def _lo_remove(x, y, c, f, tol):
    """ISIS ``LoHighDistortionMap::SetFocalPlane``: perspective factor, then radial."""
    px, py, cx, cy, k0, k1 = c
    factor = 1.0 + px * x + py * y
    pcx, pcy = x * factor, y * factor
    sx, sy = pcx - cx, pcy - cy
    r2 = sx * sx + sy * sy
    dr_over_r = np.where(r2 <= 1e-6, 0.0, k0 + k1 * r2)
    return pcx - dr_over_r * sx, pcy - dr_over_r * sy


def _lo_apply(x, y, c, f, tol):
    """The exact inverse of :func:`_lo_remove`, by Newton–Raphson.

    ISIS's ``SetUndistortedFocalPlane`` applies the two corrections in closed form,
    which inverts ``SetFocalPlane`` only to first order; solving the forward model
    keeps ground → image → ground closed to the tolerance.
    """
    def jac(u, v, h=1e-7):
        fx0, fy0 = _lo_remove(u, v, c, f, tol)
        fx1, fy1 = _lo_remove(u + h, v, c, f, tol)
        fx2, fy2 = _lo_remove(u, v + h, c, f, tol)
        return (fx1 - fx0) / h, (fx2 - fx0) / h, (fy1 - fy0) / h, (fy2 - fy0) / h

    return _newton(x, y, lambda u, v: _lo_remove(u, v, c, f, tol), jac, min(tol, 1e-10), 30)


# ---------------------------------------------------------------------------------------
# ASP / VisionWorkbench BrownConrady and Photometrix (LensDistortion.cc
# ``undistorted_coordinates``), here on coordinates relative to the principal point
# ---------------------------------------------------------------------------------------

def _brownconrady_remove(x, y, c, f, tol):
    xp, yp, k1, k2, k3, p1, p2, phi = c
    ix, iy = x - xp, y - yp
    r2 = ix * ix + iy * iy
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    tangential = r2 * (p1 + r2 * p2)
    return ix * radial - tangential * np.sin(phi), iy * radial + tangential * np.cos(phi)


def _photometrix_remove(x, y, c, f, tol):
    xp, yp, k1, k2, k3, p1, p2 = c
    ix, iy = x - xp, y - yp
    r2 = ix * ix + iy * iy
    drr = r2 * (k1 + r2 * (k2 + r2 * k3))  # dr / r
    return (x + ix * drr + p1 * (r2 + 2.0 * ix * ix) + 2.0 * p2 * ix * iy,
            y + iy * drr + p2 * (r2 + 2.0 * iy * iy) + 2.0 * p1 * ix * iy)


# ---------------------------------------------------------------------------------------
# OpenCV rational model as ISIS's OsirisRexTagcamsDistortionMap applies it (DOI-USGS/ISIS3
# isis/src/osirisrex/objs/OsirisRexTagcamsCamera/OsirisRexTagcamsDistortionMap.cpp):
# undistorted focal (u, v) mm → normalised (x', y') = (u/f, −v/f) (the detector line
# runs along −y) → x'' = x' R + 2 p1 x'y' + p2 (r² + 2x'²), y'' = y' R + p1 (r² + 2y'²)
# + 2 p2 x'y', R = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶) → distorted
# detector pixels fx (1 + a T) x'' + cx: in focal mm (ox + f sx x'', oy − f sy y'').
# ---------------------------------------------------------------------------------------

def _opencv_forward(x, y, c):
    k1, k2, k3, k4, k5, k6, p1, p2 = c[:8]
    r2 = x * x + y * y
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def _opencv_apply(x, y, c, f, tol):
    sx, sy, ox, oy = c[8:12]
    xpp, ypp = _opencv_forward(x / f, -y / f, c)
    return ox + f * sx * xpp, oy - f * sy * ypp


def _opencv_remove(x, y, c, f, tol):
    sx, sy, ox, oy = c[8:12]
    xpp, ypp = (x - ox) / (f * sx), -(y - oy) / (f * sy)

    def jac(u, v, h=1e-8):
        fx0, fy0 = _opencv_forward(u, v, c)
        fx1, fy1 = _opencv_forward(u + h, v, c)
        fx2, fy2 = _opencv_forward(u, v + h, c)
        return (fx1 - fx0) / h, (fx2 - fx0) / h, (fy1 - fy0) / h, (fy2 - fy0) / h

    xp, yp = _newton(xpp, ypp, lambda u, v: _opencv_forward(u, v, c), jac, 1e-13, 30)
    return xp * f, -yp * f


def _numeric_inverse(remove):
    """apply() of a model given by remove(): Newton–Raphson with a numerical Jacobian
    (as VisionWorkbench's ``LensDistortion::distorted_coordinates`` solver)."""
    def apply(x, y, c, f, tol):
        def jac(u, v, h=1e-7):
            fx0, fy0 = remove(u, v, c, f, tol)
            fx1, fy1 = remove(u + h, v, c, f, tol)
            fx2, fy2 = remove(u, v + h, c, f, tol)
            return (fx1 - fx0) / h, (fx2 - fx0) / h, (fy1 - fy0) / h, (fy2 - fy0) / h

        return _newton(x, y, lambda u, v: remove(u, v, c, f, tol), jac, min(tol, 1e-13), 30)

    return apply


# ---------------------------------------------------------------------------------------
# Apollo Metric (Mapping) Camera: ISIS ``ApolloMetricDistortionMap`` (DOI-USGS/ISIS3,
# isis/src/apollo/objs/ApolloMetricCamera/ApolloMetricDistortionMap.cpp), coefficients
# from the NAIF IK (INS-915240 / -916240 / -917240: _PP, _OD_K, _DECENTER)
# ---------------------------------------------------------------------------------------

def _apollo_offsets(x, y, c):
    """Radial + decentering correction at coordinates (x, y) relative to the principal
    point: ``(x D(r²) − T sin t0, y D(r²) + T cos t0)``, ``D = k1 r² + k2 r⁴ + k3 r⁶``,
    ``T = j1 r² + j2 r⁴`` (mm)."""
    _, _, k1, k2, k3, j1, j2, t0 = c
    rr = x * x + y * y
    radial = rr * (k1 + rr * (k2 + rr * k3))
    tangential = rr * (j1 + rr * j2)
    return x * radial - tangential * np.sin(t0), y * radial + tangential * np.cos(t0)


def _apollo_remove(x, y, c, f, tol):
    # ISIS SetFocalPlane: reduce to the principal point, then add the correction; the
    # undistorted coordinates are relative to the principal point (the optical axis).
    ix, iy = x - c[0], y - c[1]
    ox, oy = _apollo_offsets(ix, iy, c)
    return ix + ox, iy + oy


def _apollo_apply(x, y, c, f, tol):
    # ISIS SetUndistortedFocalPlane: fixed-point iteration t ← u − offsets(t) from t = u,
    # until both coordinates move by at most ``tol`` mm (ISIS: 1e-6, at most 50 passes);
    # points that do not converge are NaN (ISIS returns false for them).
    tx, ty = x.copy(), y.copy()
    active = np.ones(np.shape(x), dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(50):
            ox, oy = _apollo_offsets(tx, ty, c)
            nx, ny = x - ox, y - oy
            moved = (np.abs(nx - tx) > tol) | (np.abs(ny - ty) > tol)
            tx, ty = np.where(active, nx, tx), np.where(active, ny, ty)
            active &= moved
            if not active.any():
                break
    tx = np.where(active, np.nan, tx)
    ty = np.where(active, np.nan, ty)
    return tx + c[0], ty + c[1]


_APPLY = {"radial": _radial_apply, "transverse": _transverse_apply, "radtan": _radtan_apply,
          "lrolrocnac": _lroc_apply, "dawnfc": _dawn_apply, "kaguyalism": _kaguya_apply,
          "cahvor": _cahvor_apply, "lunarorbiter": _lo_apply, "brown": _brown_apply,
          "brownconrady": _numeric_inverse(_brownconrady_remove), "opencv": _opencv_apply,
          "photometrix": _numeric_inverse(_photometrix_remove), "apollometric": _apollo_apply}
_REMOVE = {"radial": _radial_remove, "transverse": _transverse_remove,
           "radtan": _radtan_remove, "lrolrocnac": _lroc_remove, "dawnfc": _dawn_remove,
           "kaguyalism": _kaguya_remove, "cahvor": _cahvor_remove, "lunarorbiter": _lo_remove,
           "brown": _brown_remove, "brownconrady": _brownconrady_remove,
           "photometrix": _photometrix_remove, "apollometric": _apollo_remove,
           "opencv": _opencv_remove}

# Distortions of ISIS cameras read from cubes (MARCI, MOC-WA: demtool.sensors.distortion_cubes)
from demtool.sensors.distortion_cubes import APPLY as _CUBE_APPLY  # noqa: E402
from demtool.sensors.distortion_cubes import COUNTS as _CUBE_COUNTS  # noqa: E402
from demtool.sensors.distortion_cubes import REMOVE as _CUBE_REMOVE  # noqa: E402

MODELS = MODELS + tuple(_CUBE_COUNTS)
_COUNTS.update(_CUBE_COUNTS)
_APPLY.update(_CUBE_APPLY)
_REMOVE.update(_CUBE_REMOVE)

# ISIS mission maps ALE writes into ISDs (New Horizons MVIC frames, THEMIS IR:
# demtool.sensors.distortion_isis)
from demtool.sensors import distortion_isis as _isis  # noqa: E402

MODELS = MODELS + ("legendre", "themisir")
_COUNTS.update(legendre=(42,), themisir=(3,))
_APPLY.update(legendre=_isis.legendre_apply, themisir=_isis.themisir_apply)
_REMOVE.update(legendre=_isis.legendre_remove, themisir=_isis.themisir_remove)
