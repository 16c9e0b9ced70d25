"""Least-squares matching (LSM) of image templates, after Grün (1985).

The left image holds the template ``f`` (a square window of ``2 h + 1`` pixels a side,
centred on an integer pixel); the right image ``g`` is resampled at the positions of
the template's pixels under an affine geometric model and a linear radiometric one::

    f(u, v) = r0 + r1 g(x', y') + e(u, v)                      (Grün 1985, eq. 5)
    x' = a0 + a1 u + a2 v,   y' = b0 + b1 u + b2 v              (eq. 10)

where ``(u, v)`` are the template offsets (column, row) from its centre.  The eight
parameters are estimated by Gauss–Newton (the linearised observation equations of
eq. 12 in Grün 1985), starting from an integer or sub-pixel approximation (x0, y0)
of the centre's position in the right image, until the shift updates fall below a
tolerance.  At convergence ``(a0, b0)`` is the sub-pixel position in the right image
of the template centre, its standard deviation is ``σ0 sqrt(Q[0, 0])`` with
``Q = (AᵀA)⁻¹`` and ``σ0² = vᵀv / (n − 8)`` (eq. 14-15), and the quality of the match
is the correlation coefficient between the template and the resampled window
(both evaluated in the last Gauss–Newton pass, within the tolerance of the solution).

The right image is resampled with Keys' (1981) cubic convolution (a = −1/2); the
image gradients in the design matrix are the exact derivatives of that interpolant,
so Gauss–Newton converges on the minimum of the interpolated problem without the
sub-pixel bias of bilinear resampling.

References
----------
Grün, A. (1985). Adaptive least squares correlation: a powerful image matching
    technique. South African Journal of Photogrammetry, Remote Sensing and
    Cartography 14(3), 175-187.
Keys, R. (1981). Cubic convolution interpolation for digital image processing.
    IEEE Trans. ASSP 29(6), 1153-1160.
"""

from __future__ import annotations

from typing import NamedTuple

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
from demtool.tiling.rows import on_row_parts

#: Gauss–Newton forms of :func:`lsm_match` (the first is the default).
LSM_METHODS = ("forward", "inverse")

STATUS_NAMES = ("converged", "not converged", "template invalid", "window invalid",
                "singular", "diverged")


class LSMResult(NamedTuple):
    """LSM solutions of N templates.

    Attributes
    ----------
    x_right, y_right : (N,) float64
        Sub-pixel position (column, row) in the right image of each template centre;
        NaN where ``status`` is not ``CONVERGED``.
    correlation : (N,) float64
        Correlation coefficient between the template and the resampled right window
        at the solution (−1 … 1); NaN where no solution.
    sigma_x : (N,) float64
        Standard deviation of ``x_right`` (pixels), ``σ0 sqrt(Q[0, 0])``; NaN where no
        solution.
    iterations : (N,) int32
        Gauss–Newton iterations used.
    status : (N,) int8
        ``CONVERGED`` (0) or the reason of the failure (see ``STATUS_NAMES``).
    affine : (N, 4) float64 or None
        The affine shape ``a1, a2, b1, b2`` of each converged solution (eq. 10;
        ``x' = a0 + a1 u + a2 v``, ``y' = b0 + b1 u + b2 v``); NaN elsewhere, and
        for ``method="inverse"``.
    """

    x_right: np.ndarray
    y_right: np.ndarray
    correlation: np.ndarray
    sigma_x: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    affine: np.ndarray | None = None


# a called kernel, not numba-inlined IR (lsm_one's compile ~4 CPU s less), with the
# caller's fast-math flags: the same instructions, LSM results identical to the bit
@njit(cache=True, fastmath=_FASTMATH)
def _keys(x: float) -> tuple[float, float]:
    """Keys (1981) cubic kernel (a = -1/2) and its derivative at signed distance x."""
    ax = abs(x)
    ax2 = ax * ax
    sign = 1.0 if x >= 0.0 else -1.0
    if ax <= 1.0:
        return 1.5 * ax2 * ax - 2.5 * ax2 + 1.0, sign * (4.5 * ax2 - 5.0 * ax)
    if ax < 2.0:
        return (-0.5 * ax2 * ax + 2.5 * ax2 - 4.0 * ax + 2.0,
                sign * (-1.5 * ax2 + 5.0 * ax - 4.0))
    return 0.0, 0.0


@njit(cache=True, inline="always")
def _cubic_sample(image: np.ndarray, xi: int, yi: int, tx: float,
                  ty: float) -> tuple[float, float, float]:
    """Cubic-convolution value and x, y derivatives at (xi + tx, yi + ty), 0 <= t < 1."""
    wx0, dx0 = _keys(tx + 1.0)
    wx1, dx1 = _keys(tx)
    wx2, dx2 = _keys(tx - 1.0)
    wx3, dx3 = _keys(tx - 2.0)
    wy0, dy0 = _keys(ty + 1.0)
    wy1, dy1 = _keys(ty)
    wy2, dy2 = _keys(ty - 1.0)
    wy3, dy3 = _keys(ty - 2.0)
    g = 0.0
    gx = 0.0
    gy = 0.0
    for m in range(4):
        line = image[yi - 1 + m]
        a0 = line[xi - 1]
        a1 = line[xi]
        a2 = line[xi + 1]
        a3 = line[xi + 2]
        rx = wx0 * a0 + wx1 * a1 + wx2 * a2 + wx3 * a3
        rdx = dx0 * a0 + dx1 * a1 + dx2 * a2 + dx3 * a3
        if m == 0:
            wy, dwy = wy0, dy0
        elif m == 1:
            wy, dwy = wy1, dy1
        elif m == 2:
            wy, dwy = wy2, dy2
        else:
            wy, dwy = wy3, dy3
        g += wy * rx
        gx += wy * rdx
        gy += dwy * rx
    return g, gx, gy


@njit(cache=True, fastmath=_FASTMATH)
def lsm_one(left: np.ndarray, left_ok: np.ndarray, right: np.ndarray, right_ok4: np.ndarray,
            row: int, col: int, x0: float, y0: float, half: int, max_iterations: int,
            tolerance: float, max_shift: float, give_up_below: float, weights: np.ndarray,
            result: np.ndarray) -> None:
    """Least-squares match of the template centred on left pixel (row, col).

    ``result`` (float64, 6 or 10) receives x_right, y_right, correlation, sigma_x,
    iterations, status (and at convergence the affine terms a1, a2, b1, b2).
    ``weights`` (template-sized, mean 1) weight the observations (ones: ordinary LSM).
    From the third iteration on, a correlation below ``give_up_below`` stops the
    iterations (status ``NOT_CONVERGED``).
    ``right_ok4[y, x]`` is True when the 4 × 4 cubic-convolution neighbourhood of
    (x + [0, 1), y + [0, 1)) is valid.  See :func:`lsm_match`.
    """
    height_r, width_r = right.shape
    if not _open_template(result, left_ok, row, col, half):
        return
    size = 2 * half + 1
    n = size * size
    for v in range(-half, half + 1):
        for u in range(-half, half + 1):
            if not left_ok[row + v, col + u]:
                result[5] = LEFT_INVALID
                return

    # parameters: a0 a1 a2 b0 b1 b2 r0 r1 (x' = a0 + a1 u + a2 v, y' = b0 + b1 u + b2 v)
    p = np.zeros(N_PARAMS)
    p[0] = x0
    p[1] = 1.0
    p[3] = y0
    p[5] = 1.0
    p[7] = 1.0
    normal = np.zeros((N_PARAMS, N_PARAMS))
    rhs = np.zeros(N_PARAMS)
    delta = np.zeros(N_PARAMS)
    lower = np.zeros((N_PARAMS, N_PARAMS))
    jac = np.zeros(N_PARAMS)

    # radiometric start values from the nearest-pixel window: match mean and contrast
    xi0 = int(np.floor(x0 + 0.5))
    yi0 = int(np.floor(y0 + 0.5))
    if (xi0 - half < 0 or yi0 - half < 0 or xi0 + half >= width_r
            or yi0 + half >= height_r):
        result[5] = RIGHT_INVALID
        return
    sf = 0.0
    sg = 0.0
    sff = 0.0
    sgg = 0.0
    for v in range(-half, half + 1):
        for u in range(-half, half + 1):
            f = left[row + v, col + u]
            g = right[yi0 + v, xi0 + u]
            sf += f
            sg += g
            sff += f * f
            sgg += g * g
    var_f = sff - sf * sf / n
    var_g = sgg - sg * sg / n
    if var_f <= 0.0 or var_g <= 0.0:
        result[5] = SINGULAR
        return
    p[7] = np.sqrt(var_f / var_g)
    p[6] = (sf - p[7] * sg) / n

    status = NOT_CONVERGED
    iteration = 0
    # Residuals, correlation and the normal matrix of the last pass serve for the
    # solution's quality and covariance: they were evaluated at most ``tolerance``
    # pixels from it, so a separate final pass would change nothing that matters.
    sum_vv = 0.0
    corr = np.nan
    while True:
        for i in range(N_PARAMS):
            rhs[i] = 0.0
            for j in range(N_PARAMS):
                normal[i, j] = 0.0
        sum_vv = 0.0
        sf = 0.0
        sg = 0.0
        sff = 0.0
        sgg = 0.0
        sfg = 0.0
        for v in range(-half, half + 1):
            for u in range(-half, half + 1):
                xs = p[0] + p[1] * u + p[2] * v
                ys = p[3] + p[4] * u + p[5] * v
                xi, yi, ok = _cubic_cell(right_ok4, xs, ys)
                if not ok:
                    result[5] = RIGHT_INVALID
                    return
                g, gx, gy = _cubic_sample(right, xi, yi, xs - xi, ys - yi)
                f = left[row + v, col + u]
                w = weights[v + half, u + half]
                residual = f - (p[6] + p[7] * g)
                jac[0] = p[7] * gx
                jac[1] = p[7] * gx * u
                jac[2] = p[7] * gx * v
                jac[3] = p[7] * gy
                jac[4] = p[7] * gy * u
                jac[5] = p[7] * gy * v
                jac[6] = 1.0
                jac[7] = g
                for i in range(N_PARAMS):
                    weighted = w * jac[i]
                    rhs[i] += weighted * residual
                    for j in range(i + 1):
                        normal[i, j] += weighted * jac[j]
                sum_vv += w * residual * residual
                sf += w * f
                sg += w * g
                sff += w * f * f
                sgg += w * g * g
                sfg += w * f * g
        var_f = sff - sf * sf / n
        var_g = sgg - sg * sg / n
        if var_f <= 0.0 or var_g <= 0.0:
            result[5] = SINGULAR
            return
        corr = (sfg - sf * sg / n) / np.sqrt(var_f * var_g)
        for i in range(N_PARAMS):
            for j in range(i + 1, N_PARAMS):
                normal[i, j] = normal[j, i]
        if iteration >= 2 and corr < give_up_below:
            result[4] = iteration
            result[5] = NOT_CONVERGED
            return
        if not _cholesky_solve(normal, rhs, delta, lower):
            result[5] = SINGULAR
            return
        for i in range(N_PARAMS):
            p[i] += delta[i]
        iteration += 1
        if _ran_away(p[0], p[1], p[2], p[3], p[4], p[5], x0, y0, max_shift) or p[7] <= 0.0:
            result[5] = DIVERGED
            return
        if abs(delta[0]) < tolerance and abs(delta[3]) < tolerance:
            status = CONVERGED
            break
        if iteration >= max_iterations:
            break
    if status != CONVERGED:
        result[4] = iteration
        result[5] = status
        return
    # covariance of a0: Q[0, 0] = e0ᵀ N⁻¹ e0
    unit = np.zeros(N_PARAMS)
    unit[0] = 1.0
    if not _cholesky_solve(normal, unit, delta, lower):
        result[5] = SINGULAR
        return
    sigma0_sq = sum_vv / (n - N_PARAMS)
    _store_solution(result, p[0], p[3], corr, np.sqrt(sigma0_sq * max(delta[0], 0.0)),
                    iteration)
    if result.shape[0] >= 10:  # the affine shape a1 a2 b1 b2
        result[6] = p[1]
        result[7] = p[2]
        result[8] = p[4]
        result[9] = p[5]


@njit(cache=True, nogil=True)
def _lsm_batch(left, left_ok, right, right_ok4, rows, cols, x0, y0, half, max_iterations,
               tolerance, max_shift, give_up_below, weights, out, start, stop):
    """:func:`lsm_one` over templates ``start … stop − 1`` (``out``: (N, 10) float64);
    run over row parts by :func:`demtool.tiling.rows.on_row_parts` (a serial ``nogil``
    kernel compiles in a fraction of a ``parallel=True`` one's time)."""
    for k in range(start, stop):
        lsm_one(left, left_ok, right, right_ok4, rows[k], cols[k], x0[k], y0[k], half,
                max_iterations, tolerance, max_shift, give_up_below, weights, out[k])


def template_weights(template: int, weighting: float) -> np.ndarray:
    """Observation weights of a template, (template, template) float64 with mean 1.

    Uniform for ``weighting`` 0, else a Gaussian of standard deviation ``weighting``
    pixels centred on the template.
    """
    if weighting < 0:
        raise ValueError(f"weighting must be >= 0, got {weighting}")
    if weighting == 0:
        return np.ones((template, template))
    offsets = np.arange(template) - template // 2
    gauss = np.exp(-0.5 * (offsets / weighting) ** 2)
    weights = np.outer(gauss, gauss)
    return weights * (weights.size / weights.sum())


def cubic_support_mask(valid: np.ndarray) -> np.ndarray:
    """True at (y, x) when the 4 × 4 pixels (y-1 … y+2, x-1 … x+2) are all valid.

    Parameters
    ----------
    valid : (H, W) bool
        True where the image has data.

    Returns
    -------
    (H, W) bool
        Where cubic convolution at any point of [x, x+1) × [y, y+1) sees only data.
    """
    valid = np.asarray(valid, dtype=bool)
    height, width = valid.shape
    out = np.zeros_like(valid)
    if height < 4 or width < 4:
        return out
    acc = np.ones((height - 3, width - 3), dtype=bool)
    for dy in range(4):
        for dx in range(4):
            acc &= valid[dy:dy + height - 3, dx:dx + width - 3]
    out[1:height - 2, 1:width - 2] = acc
    return out


def lsm_match(left: np.ndarray, right: np.ndarray, rows: np.ndarray, cols: np.ndarray,
              x_start: np.ndarray, y_start: np.ndarray, *, template: int = 17,
              left_valid: np.ndarray | None = None, right_valid: np.ndarray | None = None,
              max_iterations: int = 10, tolerance: float = 5e-3,
              max_shift: float | None = None, give_up_below: float = -1.0,
              weighting: float = 0.0, method: str = "forward") -> LSMResult:
    """Least-squares matching (Grün 1985) of templates of ``left`` in ``right``.

    Parameters
    ----------
    left, right : (H, W), (H2, W2) float
        Grey images (any DN scale); NaN = nodata.  Not modified.
    rows, cols : (N,) int
        Template centres (row, column) in the left image.
    x_start, y_start : (N,) float
        Approximate position (column, row) of each centre in the right image, within
        about a pixel (e.g. from NCC); for a rectified pair ``y_start = rows`` and
        ``x_start = cols - disparity``.
    template : int
        Template size in pixels (odd, ≥ 5).
    left_valid, right_valid : bool arrays, optional
        True where the pixel may be used (default: finite).
    max_iterations : int
        Gauss–Newton iteration limit.
    tolerance : float
        Convergence: both shift updates below this (pixels).
    max_shift : float, optional
        A solution whose shift moves farther than this from the start (pixels) has
        diverged; default half the template size.
    give_up_below : float
        Stop a template whose correlation is still below this after two iterations
        (it could not be accepted anyway); -1 never gives up.
    weighting : float
        Standard deviation (pixels) of Gaussian observation weights centred on the
        template (0: uniform weights, Grün's ordinary LSM).  Centre weighting makes
        the estimate describe the centre pixel more than the template's mean, which
        reduces the smoothing of relief finer than the template.
    method : {"forward", "inverse"}
        ``"forward"`` (default): Grün's forward-additive form with the radiometric
        parameters in the model (this module).  ``"inverse"``: inverse-compositional
        Gauss–Newton on the zero-normalised SSD (:mod:`demtool.match.icgn`; the
        Hessian is computed once per template, about 1.5× faster per template); it
        converges on the same maximum of the correlation where both converge, but
        gives up on more templates near occlusions (Middlebury teddy: 4 points less
        completeness, lower MAE), so `match` keeps Grün's form.

    Returns
    -------
    LSMResult
        Positions, correlation, σ of the x position, iterations, status per template.
    """
    if template < 5 or template % 2 == 0:
        raise ValueError(f"template must be odd and >= 5, got {template}")
    if method not in LSM_METHODS:
        raise ValueError(f"method must be one of {', '.join(LSM_METHODS)}, got {method!r}")
    left = np.asarray(left, dtype=np.float64)
    right = np.asarray(right, dtype=np.float64)
    left_ok = np.isfinite(left) if left_valid is None else (left_valid & np.isfinite(left))
    right_ok = np.isfinite(right) if right_valid is None else (right_valid & np.isfinite(right))
    left_filled = np.where(left_ok, left, 0.0)
    right_filled = np.where(right_ok, right, 0.0)
    half = template // 2
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    cols = np.ascontiguousarray(cols, dtype=np.int64)
    x_start = np.ascontiguousarray(x_start, dtype=np.float64)
    y_start = np.ascontiguousarray(y_start, dtype=np.float64)
    out = np.full((rows.shape[0], 10), np.nan)
    if rows.shape[0]:
        if method == "inverse":
            from demtool.match.icgn import icgn_batch as batch
        else:
            batch = _lsm_batch
        args = (left_filled, left_ok, right_filled, cubic_support_mask(right_ok), rows, cols,
                x_start, y_start, half, int(max_iterations), float(tolerance),
                float(half if max_shift is None else max_shift), float(give_up_below),
                template_weights(template, weighting), out)
        on_row_parts(lambda start, stop: batch(*args, start, stop), rows.shape[0])
    return LSMResult(x_right=out[:, 0], y_right=out[:, 1], correlation=out[:, 2],
                     sigma_x=out[:, 3], iterations=out[:, 4].astype(np.int32),
                     status=out[:, 5].astype(np.int8), affine=out[:, 6:])
