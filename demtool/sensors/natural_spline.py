"""The natural cubic spline of an ephemeris, without importing ``scipy.interpolate``.

:func:`demtool.sensors.isd.resample_states` resamples an ISD's positions that carry no
velocities with a natural cubic spline (ALE's ``States::getState(t, SPLINE)``, GSL's
``cspline``).  ``scipy.interpolate.CubicSpline`` computes it, but importing
``scipy.interpolate`` (with ``scipy.linalg``, ``scipy.special`` and ``scipy.optimize``)
costs about 0.8 CPU s, more than reading the whole ISD: every ``mapproject``, ``dem``
and ``bundle`` of a line scanner paid it before its first pixel.  This module does the
same arithmetic in the same order, so the values are equal to the bit (tests/sensors/
test_natural_spline.py compares them with SciPy's on random ephemerides):

* the slopes at the knots: the tridiagonal system of ``CubicSpline(x, y,
  bc_type="natural")`` (scipy/interpolate/_cubic.py: the banded matrix ``A``, the
  right-hand side ``b``), solved as LAPACK's ``dgtsv`` solves it (Gaussian elimination
  with partial pivoting by rows, then back substitution; reference LAPACK
  ``SRC/dgtsv.f``, which ``scipy.linalg.solve_banded((1, 1), …)`` calls);
* the cubic of each interval from the values and slopes (``CubicHermiteSpline``'s
  coefficients ``c[0..3]``) and its value at ``t`` as SciPy's ``_ppoly.evaluate``
  computes it (``evaluate_poly1``: ``c3 + c2·s + c1·s² + c0·s³`` summed in that order,
  the powers by repeated products; the interval by ``find_interval``: ``x[i] ≤ t <
  x[i+1]``, the last closed, the end intervals extrapolated).

Plain Python floats (IEEE double, no fused multiply-add) carry the solve: the
ephemerides hold tens to thousands of samples, so it takes well under a millisecond
per hundred.
"""

from __future__ import annotations

import numpy as np


def _gtsv(dl: list[float], d: list[float], du: list[float],
          b: list[list[float]]) -> list[list[float]]:
    """Solve the tridiagonal system (sub-diagonal ``dl``, diagonal ``d``,
    super-diagonal ``du``; ``b`` one list per row, one value per right-hand side) as
    reference LAPACK's ``dgtsv`` does; the arguments are overwritten.

    Raises
    ------
    ValueError
        The matrix is singular (``dgtsv``'s ``INFO > 0``).
    """
    n = len(d)
    du2 = [0.0] * n  # the second super-diagonal the row interchanges fill
    for i in range(n - 1):
        last = i == n - 2
        if abs(d[i]) >= abs(dl[i]):  # no row interchange
            if d[i] == 0.0:
                raise ValueError("singular spline system")
            fact = dl[i] / d[i]
            d[i + 1] = d[i + 1] - fact * du[i]
            b[i + 1] = [bn - fact * bi for bi, bn in zip(b[i], b[i + 1], strict=True)]
            if not last:
                dl[i] = 0.0
        else:  # interchange rows i and i + 1
            fact = d[i] / dl[i]
            d[i] = dl[i]
            temp = d[i + 1]
            d[i + 1] = du[i] - fact * temp
            if not last:
                dl[i] = du[i + 1]
                du[i + 1] = -fact * dl[i]
            du[i] = temp
            b[i], b[i + 1] = b[i + 1], [bi - fact * bn for bi, bn in
                                        zip(b[i], b[i + 1], strict=True)]
        if not last:
            du2[i] = dl[i]
    if d[n - 1] == 0.0:
        raise ValueError("singular spline system")
    x = [list(row) for row in b]
    x[n - 1] = [v / d[n - 1] for v in x[n - 1]]
    if n > 1:
        x[n - 2] = [(v - du[n - 2] * w) / d[n - 2] for v, w in zip(x[n - 2], x[n - 1],
                                                                   strict=True)]
    for i in range(n - 3, -1, -1):
        x[i] = [(v - du[i] * w - du2[i] * u) / d[i]
                for v, w, u in zip(x[i], x[i + 1], x[i + 2], strict=True)]
    return x


def natural_spline_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """First derivatives at the knots of the natural cubic spline through ``(x, y)``.

    Parameters
    ----------
    x : (n,) float64
        Strictly increasing knots, n ≥ 3.
    y : (n, m) float64
        Values at the knots, one column per coordinate.

    Returns
    -------
    (n, m) float64
        ``dy/dx`` at the knots (SciPy's ``CubicSpline(x, y, bc_type="natural")``
        slopes, to the bit).
    """
    dx = np.diff(x)
    dxr = dx[:, None]
    slope = np.diff(y, axis=0) / dxr
    n = len(x)
    b = np.empty_like(y)
    b[1:-1] = 3 * (dxr[1:] * slope[:-1] + dxr[:-1] * slope[1:])
    # natural ends: second derivative 0 (CubicSpline's bc (2, 0.0); its -0.5 * 0 * dx²
    # term adds a signed zero, which changes no value)
    b[0] = 3 * (y[1] - y[0])
    b[-1] = 3 * (y[-1] - y[-2])
    d = np.empty(n)
    d[1:-1] = 2 * (dx[:-1] + dx[1:])
    d[0], d[-1] = 2 * dx[0], 2 * dx[-1]
    du = np.empty(n - 1)  # du[i]: row i, column i + 1
    du[0], du[1:] = dx[0], dx[:-1]
    dl = np.empty(n - 1)  # dl[i]: row i + 1, column i
    dl[:-1], dl[-1] = dx[1:], dx[-1]
    solved = _gtsv(dl.tolist(), d.tolist(), du.tolist(), b.tolist())
    return np.asarray(solved, dtype=np.float64).reshape(y.shape)


def natural_cubic_spline(x, y, at) -> np.ndarray:
    """The natural cubic spline through ``(x, y)`` at ``at``, extrapolating the end
    intervals' cubics beyond the knots.

    Parameters
    ----------
    x : (n,) array_like
        Strictly increasing knots, n ≥ 3 (e.g. ephemeris times, seconds).
    y : (n, m) array_like
        Values at the knots (e.g. positions, metres), one column per coordinate.
    at : (k,) array_like
        Where to evaluate (same unit as ``x``).

    Returns
    -------
    (k, m) float64
        Equal to the bit to ``scipy.interpolate.CubicSpline(x, y, bc_type="natural",
        axis=0)(at)``.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    at = np.asarray(at, dtype=np.float64)
    if x.ndim != 1 or len(x) < 3 or y.shape[0] != len(x):
        raise ValueError("natural_cubic_spline needs n >= 3 knots and one value row each")
    y2 = y.reshape(len(x), -1)
    s = natural_spline_slopes(x, y2)
    # CubicHermiteSpline's coefficients (scipy/interpolate/_cubic.py)
    dxr = np.diff(x)[:, None]
    slope = np.diff(y2, axis=0) / dxr
    t = (s[:-1] + s[1:] - 2 * slope) / dxr
    c0, c1, c2, c3 = t / dxr, (slope - s[:-1]) / dxr - t, s[:-1], y2[:-1]
    # _ppoly.find_interval: x[i] <= at < x[i+1], the last interval closed, ends extrapolated
    i = np.clip(np.searchsorted(x, at, side="right") - 1, 0, len(x) - 2)
    h = (at - x[i])[:, None]
    h2 = h * h
    out = c3[i] + c2[i] * h + c1[i] * h2 + c0[i] * (h2 * h)
    return out.reshape((len(at), *y.shape[1:]))
