"""Least-squares matching by inverse-compositional Gauss–Newton (IC-GN) on ZNSSD.

The fast form of :mod:`demtool.match.lsm`.  The same affine geometric model maps the
template's offsets ``(u, v)`` into the right image::

    x' = a0 + a1 u + a2 v,   y' = b0 + b1 u + b2 v              (Grün 1985, eq. 10)

but the radiometric model is eliminated by normalising both windows (zero mean, unit
norm: the zero-normalised sum of squared differences, ZNSSD, which equals
``2 (1 − ρ)`` for the correlation coefficient ρ), and the warp is updated in the
inverse-compositional way of Baker & Matthews (2004): the increment is estimated on
the *template* side, so the Jacobian (template gradients × warp Jacobian) and the
6 × 6 Gauss–Newton Hessian are computed and factorised **once per template**, and
each iteration only resamples the right window (cubic convolution, values only) and
accumulates a 6-vector; the template gradients are Barron's four-point differences
(Pan, Li & Tong 2013, the IC-GN of digital image correlation)::

    e(u)  = (f(u) − f̄) − (Δf / Δg) (g(W(u; p)) − ḡ)
    Δp    = −H⁻¹ Σ w Jᵀ e,     H = Σ w Jᵀ J,   J = ∇f(u) ∂W/∂p
    W(p) ← W(p) ∘ W(Δp)⁻¹

Maximising ρ is what Grün's form does too (its residual is ``var(f) (1 − ρ²)``), so
both converge to the same match; the standard deviation of ``x'`` is Grün's
``σ0 sqrt(Q[0, 0])`` with ``Q`` the inverse of the 8 × 8 normal matrix of the
template-side design (the six geometric columns and the radiometric ``1`` and ``f``),
``σ0² = Σ w f̃² (1 − ρ²) / (n − 8)`` (the residual of the best gain and offset).

References
----------
Baker, S., Matthews, I. (2004). Lucas-Kanade 20 years on: a unifying framework.
    IJCV 56(3), 221-255 (section 3, the inverse compositional algorithm).
Pan, B., Li, K., Tong, W. (2013). Fast, robust and accurate digital image correlation
    calculation without redundant computations. Experimental Mechanics 53, 1277-1289.
Grün, A. (1985). Adaptive least squares correlation: a powerful image matching
    technique. S. Afr. J. Photogramm. Remote Sens. Cartogr. 14(3), 175-187.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from demtool.match.lsm_base import (
    _FASTMATH,
    CONVERGED,
    DIVERGED,
    LEFT_INVALID,
    N_PARAMS,
    NOT_CONVERGED,
    RIGHT_INVALID,
    SINGULAR,
    _cholesky_solve,
    _cubic_cell,
    _open_template,
    _ran_away,
    _store_solution,
)


@njit(cache=True, inline="always")
def _cubic_value(image: np.ndarray, xi: int, yi: int, tx: float, ty: float) -> float:
    """Cubic-convolution (Keys 1981, a = −1/2) value at (xi + tx, yi + ty), 0 <= t < 1.

    The four weights of each axis are the kernel's polynomials written out for a
    fractional part in [0, 1) (no branches).
    """
    tx2 = tx * tx
    tx3 = tx2 * tx
    wx0 = -0.5 * tx3 + tx2 - 0.5 * tx
    wx1 = 1.5 * tx3 - 2.5 * tx2 + 1.0
    wx2 = -1.5 * tx3 + 2.0 * tx2 + 0.5 * tx
    wx3 = 0.5 * tx3 - 0.5 * tx2
    ty2 = ty * ty
    ty3 = ty2 * ty
    line = image[yi - 1]
    r0 = wx0 * line[xi - 1] + wx1 * line[xi] + wx2 * line[xi + 1] + wx3 * line[xi + 2]
    line = image[yi]
    r1 = wx0 * line[xi - 1] + wx1 * line[xi] + wx2 * line[xi + 1] + wx3 * line[xi + 2]
    line = image[yi + 1]
    r2 = wx0 * line[xi - 1] + wx1 * line[xi] + wx2 * line[xi + 1] + wx3 * line[xi + 2]
    line = image[yi + 2]
    r3 = wx0 * line[xi - 1] + wx1 * line[xi] + wx2 * line[xi + 1] + wx3 * line[xi + 2]
    return ((-0.5 * ty3 + ty2 - 0.5 * ty) * r0 + (1.5 * ty3 - 2.5 * ty2 + 1.0) * r1
            + (-1.5 * ty3 + 2.0 * ty2 + 0.5 * ty) * r2 + (0.5 * ty3 - 0.5 * ty2) * r3)


@njit(cache=True, inline="always")
def _usable(left_ok: np.ndarray, r: int, c: int) -> bool:
    return 0 <= r < left_ok.shape[0] and 0 <= c < left_ok.shape[1] and left_ok[r, c]


@njit(cache=True, inline="always")
def _gradient(left: np.ndarray, left_ok: np.ndarray, r: int, c: int, dr: int,
              dc: int) -> float:
    """Derivative of ``left`` at pixel (r, c) along (dr, dc), per pixel.

    Barron's four-point central difference (f₋₂ − 8 f₋₁ + 8 f₊₁ − f₊₂) / 12, the
    template gradient of Pan et al.'s IC-GN; the two-point central difference, then
    a one-sided one, where neighbours are nodata.
    """
    p1 = _usable(left_ok, r + dr, c + dc)
    m1 = _usable(left_ok, r - dr, c - dc)
    if p1 and m1:
        if _usable(left_ok, r + 2 * dr, c + 2 * dc) and _usable(left_ok, r - 2 * dr, c - 2 * dc):
            return (left[r - 2 * dr, c - 2 * dc] - 8.0 * left[r - dr, c - dc]
                    + 8.0 * left[r + dr, c + dc] - left[r + 2 * dr, c + 2 * dc]) / 12.0
        return 0.5 * (left[r + dr, c + dc] - left[r - dr, c - dc])
    if p1:
        return left[r + dr, c + dc] - left[r, c]
    if m1:
        return left[r, c] - left[r - dr, c - dc]
    return 0.0


@njit(cache=True, fastmath=_FASTMATH)
def icgn_one(left: np.ndarray, left_ok: np.ndarray, right: np.ndarray, right_ok4: np.ndarray,
             row: int, col: int, x0: float, y0: float, half: int, max_iterations: int,
             tolerance: float, max_shift: float, give_up_below: float, weights: np.ndarray,
             work: np.ndarray, result: np.ndarray) -> None:
    """IC-GN match of the template centred on left pixel (row, col).

    Same arguments and ``result`` layout (x_right, y_right, correlation, sigma_x,
    iterations, status) as :func:`demtool.match.lsm.lsm_one`; ``work`` is a
    (template², 9) float64 scratch array (Jacobian, centred template, weight, the
    resampled right window).
    """
    if not _open_template(result, left_ok, row, col, half):
        return
    size = 2 * half + 1
    n = size * size
    # --- once per template: weighted mean / norm, Jacobian, Hessian ---------------
    sw = 0.0
    sf = 0.0
    for v in range(-half, half + 1):
        for u in range(-half, half + 1):
            if not left_ok[row + v, col + u]:
                result[5] = LEFT_INVALID
                return
            w = weights[v + half, u + half]
            sw += w
            sf += w * left[row + v, col + u]
    f_mean = sf / sw
    sff = 0.0
    hess = np.zeros((6, 6))
    normal8 = np.zeros((N_PARAMS, N_PARAMS))
    k = 0
    for v in range(-half, half + 1):
        for u in range(-half, half + 1):
            w = weights[v + half, u + half]
            f = left[row + v, col + u] - f_mean
            sff += w * f * f
            fx = _gradient(left, left_ok, row + v, col + u, 0, 1)
            fy = _gradient(left, left_ok, row + v, col + u, 1, 0)
            work[k, 0] = fx
            work[k, 1] = fx * u
            work[k, 2] = fx * v
            work[k, 3] = fy
            work[k, 4] = fy * u
            work[k, 5] = fy * v
            work[k, 6] = f
            work[k, 7] = w
            for i in range(6):
                wi = w * work[k, i]
                for j in range(i + 1):
                    hess[i, j] += wi * work[k, j]
            k += 1
    if sff <= 1e-12 * max(1.0, f_mean * f_mean * sw):
        result[5] = SINGULAR
        return
    for i in range(6):
        for j in range(i + 1, 6):
            hess[i, j] = hess[j, i]
    lower = np.zeros((N_PARAMS, N_PARAMS))
    chol6 = np.zeros((6, 6))
    rhs = np.zeros(6)
    delta = np.zeros(6)

    # warp matrix [[a1, a2, a0], [b1, b2, b0]]
    a0, a1, a2 = x0, 1.0, 0.0
    b0, b1, b2 = y0, 0.0, 1.0
    status = NOT_CONVERGED
    iteration = 0
    corr = np.nan
    while True:
        # resample the right window and its weighted statistics
        sg = 0.0
        sgg = 0.0
        sfg = 0.0
        k = 0
        for v in range(-half, half + 1):
            for u in range(-half, half + 1):
                xs = a0 + a1 * u + a2 * v
                ys = b0 + b1 * u + b2 * v
                xi, yi, ok = _cubic_cell(right_ok4, xs, ys)
                if not ok:
                    result[5] = RIGHT_INVALID
                    return
                g = _cubic_value(right, xi, yi, xs - xi, ys - yi)
                w = work[k, 7]
                sg += w * g
                sgg += w * g * g
                sfg += w * work[k, 6] * g
                work[k, 8] = g
                k += 1
        g_mean = sg / sw
        var_g = sgg - sg * g_mean
        if var_g <= 1e-12 * max(1.0, sgg):
            result[5] = SINGULAR
            return
        corr = sfg / np.sqrt(sff * var_g)  # Σ w f̃ (g − ḡ) = Σ w f̃ g (f̃ has mean 0)
        if iteration >= 2 and corr < give_up_below:
            result[4] = iteration
            result[5] = NOT_CONVERGED
            return
        scale = np.sqrt(sff / var_g)
        for i in range(6):
            rhs[i] = 0.0
        for k in range(n):
            we = work[k, 7] * (work[k, 6] - scale * (work[k, 8] - g_mean))
            for i in range(6):
                rhs[i] += we * work[k, i]
        if not _cholesky_solve(hess, rhs, delta, chol6):
            result[5] = SINGULAR
            return
        # W(p) <- W(p) o W(dp)^-1 with dp = -delta: the increment's matrix is
        # [[1 + dp1, dp2, dp0], [dp4, 1 + dp5, dp3]]; invert it and compose.
        m11 = 1.0 - delta[1]
        m12 = -delta[2]
        m21 = -delta[4]
        m22 = 1.0 - delta[5]
        t1 = -delta[0]
        t2 = -delta[3]
        det = m11 * m22 - m12 * m21
        if abs(det) < 1e-9:
            result[5] = DIVERGED
            return
        i11 = m22 / det
        i12 = -m12 / det
        i21 = -m21 / det
        i22 = m11 / det
        it1 = -(i11 * t1 + i12 * t2)
        it2 = -(i21 * t1 + i22 * t2)
        na1 = a1 * i11 + a2 * i21
        na2 = a1 * i12 + a2 * i22
        na0 = a1 * it1 + a2 * it2 + a0
        nb1 = b1 * i11 + b2 * i21
        nb2 = b1 * i12 + b2 * i22
        nb0 = b1 * it1 + b2 * it2 + b0
        step_x = na0 - a0
        step_y = nb0 - b0
        a0, a1, a2, b0, b1, b2 = na0, na1, na2, nb0, nb1, nb2
        iteration += 1
        if _ran_away(a0, a1, a2, b0, b1, b2, x0, y0, max_shift):
            result[5] = DIVERGED
            return
        if abs(step_x) < tolerance and abs(step_y) < tolerance:
            status = CONVERGED
            break
        if iteration >= max_iterations:
            break
    if status != CONVERGED:
        result[4] = iteration
        result[5] = status
        return
    # covariance of x': the 8 x 8 normal matrix of the template-side design
    # [J (6 columns), 1, f], the radiometric columns of Grün's model.
    for k in range(n):
        w = work[k, 7]
        f = work[k, 6]
        for i in range(6):
            wi = w * work[k, i]
            normal8[6, i] += wi
            normal8[7, i] += wi * f
        normal8[6, 6] += w
        normal8[7, 6] += w * f
        normal8[7, 7] += w * f * f
    for i in range(6):
        for j in range(i + 1):
            normal8[i, j] = hess[i, j]
    for i in range(N_PARAMS):
        for j in range(i + 1, N_PARAMS):
            normal8[i, j] = normal8[j, i]
    unit = np.zeros(N_PARAMS)
    unit[0] = 1.0
    q = np.zeros(N_PARAMS)
    if not _cholesky_solve(normal8, unit, q, lower):
        result[5] = SINGULAR
        return
    # Grün's residual: the best gain and offset leave Σ w e² = Σ w f̃² (1 − ρ²)
    sigma0_sq = sff * max(1.0 - corr * corr, 0.0) / (n - N_PARAMS)
    _store_solution(result, a0, b0, corr, np.sqrt(sigma0_sq * max(q[0], 0.0)), iteration)


@njit(cache=True, nogil=True)
def icgn_batch(left, left_ok, right, right_ok4, rows, cols, x0, y0, half, max_iterations,
               tolerance, max_shift, give_up_below, weights, out, start, stop):
    """:func:`icgn_one` over templates ``start … stop − 1`` (``out``: (N, 6) float64);
    run over row parts by :func:`demtool.tiling.rows.on_row_parts`."""
    n = (2 * half + 1) ** 2
    work = np.empty((n, 9))
    for k in range(start, stop):
        icgn_one(left, left_ok, right, right_ok4, rows[k], cols[k], x0[k], y0[k], half,
                 max_iterations, tolerance, max_shift, give_up_below, weights, work, out[k])
