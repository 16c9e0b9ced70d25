"""Compiled (numba) kernels of the shape-from-shading solver in :mod:`demtool.refine.sfs`.

Each kernel fuses what would otherwise be a dozen full-array numpy passes (and their
temporaries) into one loop over rows; all arrays are float32 (H, W), C order.  The
compiled loops are serial ``nogil`` kernels over a row range ``start … stop`` (the
``_…_rows`` functions), run over contiguous parts of the rows on the calling thread and
its helpers by :func:`demtool.tiling.rows.on_row_parts` (every core untiled, a tile's
share under ``--workers``).  Each part writes only its own rows, so the outputs are one
thread's, bit for bit, whatever the thread count; the sums are kept per row and added
in row order afterwards (also independent of the thread count).  numba's
``parallel=True`` gave the same loops on the same cores but made a fresh install compile
them for several times longer (its parfor pass and gufunc wrapper).  The row kernels use
numpy's error model, as numba's parfor loops did: with Python's, every division checks
for zero and raises, and the loops no longer vectorise (``reflectance_partials`` 4×
slower).

The photometric kernel evaluates the reflectance models of
:mod:`demtool.imaging.reflectance` with their analytic partial derivatives (McEwen 1991,
eq. 4 for lunar-Lambert); models without a compiled form use the numpy path of
:func:`demtool.refine.shading.reflectance_and_gradient` instead
(:data:`COMPILED_MODELS`).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from demtool.tiling.rows import on_row_parts

#: Reflectance models with a compiled kernel, name → code used by the kernels.
COMPILED_MODELS: dict[str, int] = {"lunar-lambert": 0, "lambert": 1}

#: Cosines are clamped to this before dividing (as :mod:`demtool.imaging.reflectance`).
_COSINE_FLOOR = 1e-6


def reflectance_partials(p: np.ndarray, q: np.ndarray, sun: np.ndarray, view: np.ndarray,
                         limb: float, model: int, out_r: np.ndarray, out_rp: np.ndarray,
                         out_rq: np.ndarray) -> None:
    """Unit-albedo reflectance R(p, q) and ∂R/∂p, ∂R/∂q into ``out_*``.

    ``model`` 0: lunar-Lambert ``R = 2L μ0/(μ0 + μ) + (1 − L) μ0`` (0 where μ0 ≤ 0 or
    μ ≤ 0; partials of the lit branch at the clamped cosines); 1: Lambert ``max(μ0, 0)``
    (∂R/∂μ0 = 1).  ``limb`` is McEwen's L(α).  Chain rule through
    ``μ = (d_z − p d_x − q d_y)/N``, ``N = sqrt(1 + p² + q²)``:
    ``∂μ/∂p = −d_x/N − μ p/N²`` (Horn 1990, eq. 1–2).
    """
    on_row_parts(lambda start, stop: _reflectance_partials_rows(
        p, q, sun, view, limb, model, out_r, out_rp, out_rq, start, stop), p.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _reflectance_partials_rows(p, q, sun, view, limb, model, out_r, out_rp, out_rq,
                               start, stop):  # pragma: no cover - compiled
    width = p.shape[1]
    sx, sy, sz = sun[0], sun[1], sun[2]
    vx, vy, vz = view[0], view[1], view[2]
    for r in range(start, stop):
        for c in range(width):
            pp = np.float64(p[r, c])
            qq = np.float64(q[r, c])
            inv = 1.0 / math.sqrt(1.0 + pp * pp + qq * qq)
            mu0 = (sz - pp * sx - qq * sy) * inv
            mu = (vz - pp * vx - qq * vy) * inv
            if model == 0:
                c0 = max(mu0, _COSINE_FLOOR)
                cv = max(mu, _COSINE_FLOOR)
                it = 1.0 / (c0 + cv)
                value = 2.0 * limb * c0 * it + (1.0 - limb) * c0 if (mu0 > 0 and mu > 0) \
                    else 0.0
                d_mu0 = 2.0 * limb * cv * it * it + (1.0 - limb)
                d_mu = -2.0 * limb * c0 * it * it
            else:
                value = max(mu0, 0.0)
                d_mu0 = 1.0
                d_mu = 0.0
            inv2 = inv * inv
            out_r[r, c] = value
            out_rp[r, c] = d_mu0 * (-sx * inv - mu0 * pp * inv2) \
                + d_mu * (-vx * inv - mu * pp * inv2)
            out_rq[r, c] = d_mu0 * (-sy * inv - mu0 * qq * inv2) \
                + d_mu * (-vy * inv - mu * qq * inv2)


def central_gradient(z: np.ndarray, aspect: float, gx: np.ndarray, gy: np.ndarray) -> None:
    """G z into ``gx``, ``gy``: central differences, mirrored borders (``z[−1] = z[0]``);
    ``gy`` points up (−rows) and is scaled by ``aspect = dx / dy``."""
    on_row_parts(lambda start, stop: _central_gradient_rows(z, aspect, gx, gy, start, stop),
                 z.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _central_gradient_rows(z, aspect, gx, gy, start, stop):  # pragma: no cover - compiled
    height, width = z.shape
    half = np.float32(0.5)
    half_y = np.float32(-0.5 * aspect)
    for r in range(start, stop):
        up = max(r - 1, 0)
        down = min(r + 1, height - 1)
        for c in range(width):
            left = max(c - 1, 0)
            right = min(c + 1, width - 1)
            gx[r, c] = half * (z[r, right] - z[r, left])
            gy[r, c] = half_y * (z[down, c] - z[up, c])


def slope_step(p: np.ndarray, q: np.ndarray, gx: np.ndarray, gy: np.ndarray, R: np.ndarray,
               Rp: np.ndarray, Rq: np.ndarray, normalised: np.ndarray, weight: np.ndarray,
               bp: np.ndarray, bq: np.ndarray, gamma: float, delta: float, damping: float,
               p_out: np.ndarray, q_out: np.ndarray) -> None:
    """One Gauss–Newton step of EI + δ Egrad + γ Eint in (p, q) at every pixel.

    Solves ``(c I + w u uᵀ) Δ = b`` with ``u = (∂R/∂p, ∂R/∂q)``, ``c = γ + δ + λ``
    (Egrad's Hessian δ fᵀf majorised by δ I since ‖f‖ ≤ 1; λ the Levenberg–Marquardt
    damping) and ``b = w (I/ρ − R) u − γ (p − Gz) − δ fᵀf (p − p0)`` by
    Sherman–Morrison: ``Δ = (b − u k)/c``, ``k = w uᵀb / (c + w |u|²)``.
    """
    on_row_parts(lambda start, stop: _slope_step_rows(
        p, q, gx, gy, R, Rp, Rq, normalised, weight, bp, bq, gamma, delta, damping, p_out,
        q_out, start, stop), p.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _slope_step_rows(p, q, gx, gy, R, Rp, Rq, normalised, weight, bp, bq, gamma, delta,
                     damping, p_out, q_out, start, stop):  # pragma: no cover - compiled
    width = p.shape[1]
    c_total = gamma + delta + damping
    for r in range(start, stop):
        for c in range(width):
            w = weight[r, c]
            up = Rp[r, c]
            uq = Rq[r, c]
            w_res = w * (normalised[r, c] - R[r, c])
            bx = w_res * up - gamma * (p[r, c] - gx[r, c]) - delta * bp[r, c]
            by = w_res * uq - gamma * (q[r, c] - gy[r, c]) - delta * bq[r, c]
            k = w * (up * bx + uq * by) / (c_total + w * (up * up + uq * uq))
            p_out[r, c] = p[r, c] + (bx - up * k) / c_total
            q_out[r, c] = q[r, c] + (by - uq * k) / c_total


def integrability_adjoint(p: np.ndarray, q: np.ndarray, gx: np.ndarray, gy: np.ndarray,
                          aspect: float, out: np.ndarray) -> None:
    """``Gᵀ (p − gx, q − gy)`` into ``out``: the adjoint of :func:`central_gradient` applied
    to the integrability residual (the mirrored border of G folds into the edge pixels)."""
    on_row_parts(lambda start, stop: _integrability_adjoint_rows(
        p, q, gx, gy, aspect, out, start, stop), p.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _integrability_adjoint_rows(p, q, gx, gy, aspect, out, start,
                                stop):  # pragma: no cover - compiled
    height, width = p.shape
    half = np.float32(0.5)
    half_y = np.float32(-0.5 * aspect)
    for r in range(start, stop):
        for c in range(width):
            # x part: (Gxᵀ e)[c] = ½ (e[c−1] − e[c+1]), e[−1] = −e[0], e[W] = −e[W−1]
            if width == 1:
                sx = np.float32(0.0)
            elif c == 0:
                sx = -(p[r, 0] - gx[r, 0]) - (p[r, 1] - gx[r, 1])
            elif c == width - 1:
                sx = (p[r, c - 1] - gx[r, c - 1]) + (p[r, c] - gx[r, c])
            else:
                sx = (p[r, c - 1] - gx[r, c - 1]) - (p[r, c + 1] - gx[r, c + 1])
            if height == 1:
                sy = np.float32(0.0)
            elif r == 0:
                sy = -(q[0, c] - gy[0, c]) - (q[1, c] - gy[1, c])
            elif r == height - 1:
                sy = (q[r - 1, c] - gy[r - 1, c]) + (q[r, c] - gy[r, c])
            else:
                sy = (q[r - 1, c] - gy[r - 1, c]) - (q[r + 1, c] - gy[r + 1, c])
            out[r, c] = half * sx + half_y * sy


def energy_sums(p: np.ndarray, q: np.ndarray, gx: np.ndarray, gy: np.ndarray,
                p0: np.ndarray, q0: np.ndarray, bp: np.ndarray, bq: np.ndarray,
                R: np.ndarray, normalised: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The sums, as a (3,) float64 array, of ``w (I/ρ − R)²``, of ``(p − p0)·bp +
    (q − q0)·bq`` (= ‖f(p − p0)‖² + ‖f(q − q0)‖² when ``bp = fᵀf (p − p0)``) and of
    ``(p − gx)² + (q − gy)²``.

    Rows are summed in float32 (vectorised; relative error ~1e-6 for a row of a few
    thousand pixels), the row sums in float64, in row order.
    """
    rows = np.empty((p.shape[0], 3))
    on_row_parts(lambda start, stop: _energy_sums_rows(
        p, q, gx, gy, p0, q0, bp, bq, R, normalised, weight, rows, start, stop), p.shape[0])
    return np.cumsum(rows, axis=0)[-1]  # in row order (a sum would add pairwise)


@nb.njit(cache=True, fastmath=True, nogil=True, error_model="numpy")
def _energy_sums_rows(p, q, gx, gy, p0, q0, bp, bq, R, normalised, weight, rows, start,
                      stop):  # pragma: no cover - compiled
    width = p.shape[1]
    for r in range(start, stop):
        e_i = np.float32(0.0)
        e_grad = np.float32(0.0)
        e_int = np.float32(0.0)
        for c in range(width):
            res = normalised[r, c] - R[r, c]
            e_i += weight[r, c] * res * res
            e_grad += (p[r, c] - p0[r, c]) * bp[r, c] + (q[r, c] - q0[r, c]) * bq[r, c]
            dp = p[r, c] - gx[r, c]
            dq = q[r, c] - gy[r, c]
            e_int += dp * dp + dq * dq
        rows[r, 0] = e_i
        rows[r, 1] = e_grad
        rows[r, 2] = e_int


def height_update(z_hat: np.ndarray, correction_hat: np.ndarray, laplacian: np.ndarray,
                  anchor_hat: np.ndarray, inverse_denominator: np.ndarray, gamma: float,
                  out: np.ndarray) -> None:
    """DCT-domain height step ``(γ (λ ẑ + ĉ) + a) / (γ λ + τ g²)`` into ``out``, with
    ``a = τ g² ẑ0`` and the inverse denominator precomputed."""
    on_row_parts(lambda start, stop: _height_update_rows(
        z_hat, correction_hat, laplacian, anchor_hat, inverse_denominator, gamma, out,
        start, stop), z_hat.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _height_update_rows(z_hat, correction_hat, laplacian, anchor_hat, inverse_denominator,
                        gamma, out, start, stop):  # pragma: no cover - compiled
    width = z_hat.shape[1]
    for r in range(start, stop):
        for c in range(width):
            out[r, c] = (gamma * (laplacian[r, c] * z_hat[r, c] + correction_hat[r, c])
                         + anchor_hat[r, c]) * inverse_denominator[r, c]


def weighted_square_sum(weight: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """``Σ weight (a − b)²`` (rows in float32, row sums in float64 in row order; Edepth in
    the DCT domain)."""
    rows = np.empty(a.shape[0])
    on_row_parts(lambda start, stop: _weighted_square_sum_rows(weight, a, b, rows, start,
                                                               stop), a.shape[0])
    return float(np.cumsum(rows)[-1])  # in row order (a sum would add pairwise)


@nb.njit(cache=True, fastmath=True, nogil=True, error_model="numpy")
def _weighted_square_sum_rows(weight, a, b, rows, start, stop):  # pragma: no cover
    width = a.shape[1]
    for r in range(start, stop):
        total = np.float32(0.0)
        for c in range(width):
            d = a[r, c] - b[r, c]
            total += weight[r, c] * d * d
        rows[r] = total


def block_mean(values: np.ndarray, reference: np.ndarray, block: int,
               out: np.ndarray) -> None:
    """Means of ``values − reference`` over ``block × block`` blocks into ``out``
    (``(H/b, W/b)``; b divides H and W)."""
    on_row_parts(lambda start, stop: _block_mean_rows(values, reference, block, out, start,
                                                      stop), out.shape[0],
                 min_rows=max(1, 64 // max(1, block)))


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _block_mean_rows(values, reference, block, out, start,
                     stop):  # pragma: no cover - compiled
    cols_out = out.shape[1]
    scale = np.float32(1.0 / (block * block))
    for i in range(start, stop):
        for j in range(cols_out):
            total = np.float32(0.0)
            for a in range(i * block, i * block + block):
                for b in range(j * block, j * block + block):
                    total += values[a, b] - reference[a, b]
            out[i, j] = total * scale


def block_replicate(coarse: np.ndarray, block: int, out: np.ndarray) -> None:
    """Each pixel takes its block's value: b² times the adjoint of :func:`block_mean`."""
    on_row_parts(lambda start, stop: _block_replicate_rows(coarse, block, out, start, stop),
                 out.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _block_replicate_rows(coarse, block, out, start, stop):  # pragma: no cover - compiled
    width = out.shape[1]
    for r in range(start, stop):
        i = r // block
        for c in range(width):
            out[r, c] = coarse[i, c // block]
