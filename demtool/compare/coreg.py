"""Co-registration of a DEM to a reference: vertical offset and Nuth & Kääb shift.

Conventions.  A shift ``(dx_px, dy_px, dz)`` is the translation that, **added** to the
DEM, aligns it with the reference: ``aligned[y, x] = dem[y − dy, x − dx] + dz``, with x
to the right and y down in pixels of the comparison grid and dz in metres (see
:func:`demtool.compare.grids.shift_dem`).

Methods
-------
* :func:`vertical_offset` — the median of ``reference − dem``.
* :func:`nuth_kaab` — horizontal and vertical shift.  Nuth & Kääb (2011, The
  Cryosphere 5, 271–290, eq. 3) fit ``dh / tan(slope) = a cos(b − aspect) + c`` to
  binned elevation differences; that sinusoid is the first-order Taylor expansion
  ``dh ≈ −t · ∇z + dz`` of a translated surface, divided by the slope.  We solve the
  expansion itself — ``dh = δx ∂z/∂x + δy ∂z/∂y − δz`` — by least squares over every
  valid pixel (no binning, no division by a small slope), then shift the DEM by the
  accumulated shift and repeat until the increment is below a tolerance.  Both DEMs
  are compared after the same Gaussian smoothing (σ = 1 px), the DEM's shift applied
  by the same convolution, so interpolation cannot bias the result.  This is a
  Gauss–Newton / Lucas–Kanade (1981) iteration on the same model; it stays well
  conditioned on near-flat terrain, where ``dh / tan(slope)`` is dominated by noise,
  and it gives a parameter covariance.  A coarse level (σ = 3 px) run first widens
  the capture range to several pixels.
* ICP lives in :mod:`demtool.compare.icp`, the chaining in :mod:`demtool.compare.align`.

Uncertainty.  Every fit reports the standard deviation of its parameters as the larger
of the formal least-squares value ``σ² (GᵀG)⁻¹`` (σ² the residual variance) and a block
bootstrap (pixels grouped in square blocks so that spatially correlated residuals are
resampled together; Künsch 1989).  Both grow as the terrain's slopes vanish.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from demtool.compare.shifts import gaussian_shift
from demtool.errors import ProcessingError
from demtool.imaging.robust import nmad
from demtool.logs import get_logger

__all__ = ["ShiftResult", "nuth_kaab", "vertical_offset"]

log = get_logger(__name__)

MIN_PIXELS = 100


@dataclass(frozen=True)
class ShiftResult:
    """A fitted translation and its uncertainty.

    Attributes
    ----------
    dx_px, dy_px : float
        Horizontal shift to add to the DEM, pixels (x right, y down).
    dz : float
        Vertical shift to add, metres.
    sigma_dx_px, sigma_dy_px, sigma_dz : float
        One-sigma uncertainties (inf when the terrain cannot constrain the shift).
    iterations : int
        Iterations used (1 for the offset).
    converged : bool
        Whether the last increment was below the tolerance.
    count : int
        Pixels used in the last fit (after outlier rejection).
    """

    dx_px: float
    dy_px: float
    dz: float
    sigma_dx_px: float
    sigma_dy_px: float
    sigma_dz: float
    iterations: int = 1
    converged: bool = True
    count: int = 0


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def _check_pair(dem: np.ndarray, reference: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    if dem.shape != reference.shape or dem.ndim != 2:
        raise ValueError(f"dem and reference must be 2-D arrays of one shape, got {dem.shape} "
                         f"and {reference.shape}")
    usable = np.isfinite(reference)
    if mask is not None:
        if mask.shape != dem.shape:
            raise ValueError(f"mask has shape {mask.shape}, DEM has {dem.shape}")
        usable &= mask.astype(bool)
    return usable


def _block_grid(shape: tuple[int, int], n_target: int = 64) -> tuple[int, int, int]:
    """:func:`_block_ids`' square blocks: their side (pixels, at least 8; about
    ``n_target`` blocks over the grid) and how many rows and columns of them."""
    side = max(8, int(np.sqrt(shape[0] * shape[1] / n_target)))
    return side, (shape[0] - 1) // side + 1, (shape[1] - 1) // side + 1


def _block_ids(shape: tuple[int, int], n_target: int = 64) -> np.ndarray:
    """Square blocks, about ``n_target`` of them over the grid (at least 8 px wide),
    numbered row by row."""
    side, _, block_cols = _block_grid(shape, n_target)
    rows = np.arange(shape[0]) // side
    cols = np.arange(shape[1]) // side
    return rows[:, None] * block_cols + cols[None, :]


@njit(nogil=True, cache=True)
def _block_normal_equations(design, target, block, part, parts, normal, rhs):
    """Per block ``b`` with ``b % parts == part``, Σ design_i · design_j and
    Σ design_i · target over its samples into ``normal[b]`` (p·p) and ``rhs[b]`` (p), added
    in sample order (as ``np.bincount`` adds its weights): threads given the other parts
    fill the other blocks, each block's sums the same."""
    n_params = design.shape[1]
    for row in range(design.shape[0]):
        b = block[row]
        if b % parts != part:
            continue
        for i in range(n_params):
            for j in range(n_params):
                normal[b, i * n_params + j] += design[row, i] * design[row, j]
            rhs[b, i] += design[row, i] * target[row]


def _bootstrap_sigma(design: np.ndarray, target: np.ndarray, blocks: np.ndarray, *,
                     replicates: int = 300, seed: int = 0, threads: bool = False
                     ) -> np.ndarray:
    """Std of least-squares solutions when whole blocks are resampled with replacement.

    ``blocks``: non-negative block ids (:func:`_block_ids`); the normal equations of each
    block are summed once (``threads``: the even and the odd blocks on two threads, the
    same sums), so each replicate costs one sum over blocks.
    """
    from demtool.compare.threads import both

    # the blocks present, and each sample's index among them (np.unique's, without a sort)
    ids = np.flatnonzero(np.bincount(blocks))
    n_params = design.shape[1]
    if ids.size < 8:
        return np.full(n_params, np.nan)
    position = np.zeros(int(ids[-1]) + 1, dtype=np.int64)
    position[ids] = np.arange(ids.size)
    normal = np.zeros((ids.size, n_params * n_params))
    rhs = np.zeros((ids.size, n_params))
    args = (np.ascontiguousarray(design, dtype=np.float64),
            np.ascontiguousarray(target, dtype=np.float64), position[blocks])
    if threads:
        both(lambda: _block_normal_equations(*args, 0, 2, normal, rhs),
             lambda: _block_normal_equations(*args, 1, 2, normal, rhs), on=True)
    else:
        _block_normal_equations(*args, 0, 1, normal, rhs)
    return _replicate_blocks(normal, rhs, replicates=replicates, seed=seed)


def _replicate_blocks(normal: np.ndarray, rhs: np.ndarray, *, replicates: int = 300,
                      seed: int = 0) -> np.ndarray:
    """:func:`_bootstrap_sigma` from the blocks' normal equations (``normal``: (blocks,
    p·p), ``rhs``: (blocks, p), the blocks present in increasing id): the std of the
    solutions of ``replicates`` resamplings of whole blocks with replacement."""
    blocks, n_params = rhs.shape
    if blocks < 8:
        return np.full(n_params, np.nan)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, blocks, size=(replicates, blocks))
    weights = np.zeros((replicates, blocks))
    np.add.at(weights, (np.repeat(np.arange(replicates), blocks), draws.ravel()), 1.0)
    sums = (weights @ normal).reshape(replicates, n_params, n_params)
    rhs_sums = weights @ rhs
    try:
        solutions = np.linalg.solve(sums, rhs_sums[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return np.full(n_params, np.inf)
    return solutions.std(axis=0, ddof=1)


def _solve(design: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares with formal covariance; inf variance for unconstrained directions."""
    normal = design.T @ design
    rhs = design.T @ target
    scale = np.sqrt(np.diag(normal))
    scale[scale == 0] = 1.0
    scaled = normal / np.outer(scale, scale)
    eigval, eigvec = np.linalg.eigh(scaled)
    well = eigval > 1e-10 * eigval.max()
    inv_scaled = (eigvec[:, well] / eigval[well]) @ eigvec[:, well].T
    inverse = inv_scaled / np.outer(scale, scale)
    params = inverse @ rhs
    residual = target - design @ params
    dof = max(target.size - design.shape[1], 1)
    variance = float(residual @ residual / dof)
    sigma = np.sqrt(np.maximum(np.diag(inverse), 0.0) * variance)
    if not well.all():
        # directions the data cannot see: infinite uncertainty on the touched parameters
        touched = np.abs(eigvec[:, ~well]).max(axis=1) > 1e-6
        sigma[touched] = np.inf
    return params, sigma, variance


# --------------------------------------------------------------------------------------
# vertical offset
# --------------------------------------------------------------------------------------


def vertical_offset(dem: np.ndarray, reference: np.ndarray, *,
                    mask: np.ndarray | None = None) -> ShiftResult:
    """Median vertical offset: the ``dz`` to add to the DEM so its median error is zero.

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid, on one grid
    mask : (H, W) bool, optional
        True where pixels may be used (e.g. stable terrain).

    Returns
    -------
    ShiftResult
        ``dz = median(reference − dem)``; its sigma is 1.2533 · NMAD / √n (the
        asymptotic standard error of a median) or the block-bootstrap value if larger.
    """
    usable = _check_pair(dem, reference, mask) & np.isfinite(dem)
    count = int(usable.sum())
    if count < MIN_PIXELS:
        raise ProcessingError(f"only {count} common valid pixels (need {MIN_PIXELS}) for the "
                              "vertical offset")
    dh = (reference - dem)[usable]
    dz = float(np.median(dh))
    sigma = 1.2533 * nmad(dh) / np.sqrt(count)
    return ShiftResult(0.0, 0.0, dz, 0.0, 0.0, float(sigma), 1, True, count)


# --------------------------------------------------------------------------------------
# Nuth & Kääb (linearised)
# --------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)  # serial (parallel compiled in 13 CPU s against 3.7); the
def _gradient_rows(grad_x, grad_y, dh, usable, params, centre, halfwidth, first, stop,
                   partial):  # caller splits the rows over threads (_gradient_sums)
    # Normal equations of dh = p0 gx + p1 gy - p2 over usable pixels with finite dh,
    # optionally only where |dh - model(params) - centre| <= halfwidth (halfwidth > 0).
    # partial[r] for rows first..stop-1: the row's sums of gx², gx gy, -gx, gy², -gy, 1,
    # gx dh, gy dh, -dh, dh².
    cols = dh.shape[1]
    for r in range(first, stop):
        # ten scalar sums, not an array: no allocation code to compile (same order of
        # additions, so the same bits)
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = 0.0
        for c in range(cols):
            if not usable[r, c]:
                continue
            d = dh[r, c]
            gx = grad_x[r, c]
            gy = grad_y[r, c]
            if not (np.isfinite(d) and np.isfinite(gx) and np.isfinite(gy)):
                continue
            if halfwidth > 0.0:
                model = params[0] * gx + params[1] * gy - params[2]
                if abs(d - model - centre) > halfwidth:
                    continue
            s0 += gx * gx
            s1 += gx * gy
            s2 -= gx
            s3 += gy * gy
            s4 -= gy
            s5 += 1.0
            s6 += gx * d
            s7 += gy * d
            s8 -= d
            s9 += d * d
        partial[r, 0] = s0
        partial[r, 1] = s1
        partial[r, 2] = s2
        partial[r, 3] = s3
        partial[r, 4] = s4
        partial[r, 5] = s5
        partial[r, 6] = s6
        partial[r, 7] = s7
        partial[r, 8] = s8
        partial[r, 9] = s9


def _gradient_sums(grad_x, grad_y, dh, usable, params, centre, halfwidth, *,
                   threads: bool = False) -> np.ndarray:
    """The ten sums of :func:`_gradient_rows` over the grid: each row's sums, then their
    sum over the rows in row order, so one thread or two (``threads``: the halves of the
    rows at once) give the same numbers."""
    from demtool.compare.threads import both

    rows = dh.shape[0]
    partial = np.zeros((rows, 10))
    half = rows // 2
    args = (grad_x, grad_y, dh, usable, np.asarray(params, dtype=np.float64), float(centre),
            float(halfwidth))
    both(lambda: _gradient_rows(*args, 0, half, partial),
         lambda: _gradient_rows(*args, half, rows, partial), on=threads)
    # numpy sums axis 0 of a C-ordered array row after row: the rows added in row order,
    # as the one-kernel version did (the same sums, to the bit; tested)
    return partial.sum(axis=0)


def _solve_sums(sums: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Solve the 3 × 3 normal equations of :func:`_gradient_sums`; formal sigmas."""
    normal = np.array([[sums[0], sums[1], sums[2]],
                       [sums[1], sums[3], sums[4]],
                       [sums[2], sums[4], sums[5]]])
    rhs = sums[6:9]
    count = int(round(sums[5]))
    scale = np.sqrt(np.diag(normal))
    scale[scale == 0] = 1.0
    eigval, eigvec = np.linalg.eigh(normal / np.outer(scale, scale))
    well = eigval > 1e-10 * max(eigval.max(), 1e-300)
    inverse = ((eigvec[:, well] / eigval[well]) @ eigvec[:, well].T) / np.outer(scale, scale)
    params = inverse @ rhs
    residual_ss = max(sums[9] - 2 * params @ rhs + params @ normal @ params, 0.0)
    variance = residual_ss / max(count - 3, 1)
    sigma = np.sqrt(np.maximum(np.diag(inverse), 0.0) * variance)
    if not well.all():
        touched = np.abs(eigvec[:, ~well]).max(axis=1) > 1e-6
        sigma[touched] = np.inf
        params[touched & (np.arange(3) < 2)] = 0.0
    return params, sigma, variance, count


def _eroded(mask: np.ndarray, iterations: int) -> np.ndarray:
    """``scipy.ndimage.binary_erosion(mask, iterations=...)``: each pass keeps a cell
    where it and its four neighbours are True, outside the array counting as False
    (scipy's cross-shaped default structure and ``border_value=0``); the same booleans,
    without importing scipy.ndimage (0.5 CPU s of every fuse and compare process)."""
    out = np.asarray(mask, dtype=bool)
    for _ in range(iterations):
        kept = out.copy()
        kept[1:] &= out[:-1]
        kept[:-1] &= out[1:]
        kept[:, 1:] &= out[:, :-1]
        kept[:, :-1] &= out[:, 1:]
        kept[0] = kept[-1] = False
        kept[:, 0] = kept[:, -1] = False
        out = kept
    return out


def _gradient_fit(dem: np.ndarray, reference: np.ndarray, usable: np.ndarray,
                  shift: np.ndarray, *, sigma_px: float, max_iterations: int,
                  tolerance_px: float, max_step_px: float
                  ) -> tuple[np.ndarray, int, bool, dict[str, Any]]:
    from demtool.compare.threads import both, threaded

    two = threaded(dem.size)
    dem = np.ascontiguousarray(dem, dtype=np.float64)
    # the shifted DEM, its pass along x and dh: filled anew in each iteration (the same
    # numbers as new arrays; on a 4096² grid each is 128 MB of fresh pages)
    shifted, along_x, dh = (np.empty(dem.shape) for _ in range(3))
    reference = gaussian_shift(reference, 0.0, 0.0, sigma_px, scratch=along_x)
    # metres per pixel, y down, x right (each axis as np.gradient(reference) has it)
    grad_y, grad_x = both(lambda: np.gradient(reference, axis=0),
                          lambda: np.gradient(reference, axis=1), on=two)
    # Fix the pixel set for the level: where the DEM, shifted as it starts, is valid,
    # eroded by 2 px, so that holes and edges moving with the shift do not change the
    # objective from one iteration to the next (which would stall convergence).
    start = np.isfinite(gaussian_shift(dem, shift[0], shift[1], sigma_px, out=shifted,
                                       scratch=along_x))
    usable = np.ascontiguousarray(usable & _eroded(start, 2))
    converged = False
    last: dict[str, Any] = {}
    iteration = 0
    subsample = max(1, int(np.sqrt(dem.size / 250_000)))  # for the robust thresholds
    for iteration in range(1, max_iterations + 1):  # noqa: B007 - used after the loop
        aligned = gaussian_shift(dem, shift[0], shift[1], sigma_px, out=shifted,
                                 scratch=along_x)
        aligned += shift[2]
        np.subtract(aligned, reference, out=dh)
        sums = _gradient_sums(grad_x, grad_y, dh, usable, np.zeros(3), 0.0, 0.0,
                              threads=two)
        if sums[5] < MIN_PIXELS:
            raise ProcessingError(f"only {int(sums[5])} common valid pixels (need "
                                  f"{MIN_PIXELS}) after shifting by ({shift[0]:.2f}, "
                                  f"{shift[1]:.2f}) px; the DEMs barely overlap")
        params, _, _, _ = _solve_sums(sums)
        # one pass of outlier rejection at 4 NMAD of the residuals (subsampled median)
        sub = (slice(None, None, subsample), slice(None, None, subsample))
        residual = (dh[sub] - (params[0] * grad_x[sub] + params[1] * grad_y[sub]
                               - params[2]))[usable[sub]]
        residual = residual[np.isfinite(residual)]
        centre = float(np.median(residual)) if residual.size else 0.0
        halfwidth = 4.0 * nmad(residual, median=centre) if residual.size else 0.0
        if halfwidth > 0:
            sums = _gradient_sums(grad_x, grad_y, dh, usable, params, centre, halfwidth,
                                  threads=two)
            params, sigma, variance, count = _solve_sums(sums)
        else:
            params, sigma, variance, count = _solve_sums(sums)
        step = float(np.hypot(params[0], params[1]))
        if step > max_step_px:
            params = params * (max_step_px / step)
        last = {"dh": dh, "grad_x": grad_x, "grad_y": grad_y, "usable": usable,
                "params": params, "centre": centre, "halfwidth": halfwidth,
                "sigma": sigma, "variance": variance, "count": count, "step": step}
        shift = shift + params
        if step < tolerance_px:
            converged = True
            break
    return shift, iteration, converged, last


@njit(nogil=True, cache=True)
def _gradient_block_equations(dh, grad_x, grad_y, usable, p0, p1, p2, centre, halfwidth,
                              side, block_cols, part, parts, normal, rhs, count):
    """:func:`_block_normal_equations` of Nuth & Kääb's design rows ``(∂z/∂x, ∂z/∂y, −1)``
    and target dh, read from the grids in row order: the cells that are usable and
    finite and (``halfwidth`` > 0) within ``halfwidth`` of the model ``p0 x + p1 y − p2``
    plus ``centre``, in blocks of ``side`` px, ``block_cols`` a row (:func:`_block_ids`),
    with ``b % parts == part``; ``count[b]`` their number.  The samples, their order and
    the operations of the samples picked and stacked into a design matrix, so the same
    sums."""
    height, width = dh.shape
    for r in range(height):
        first = (r // side) * block_cols
        for c in range(width):
            b = first + c // side
            if b % parts != part or not usable[r, c]:
                continue
            d, x, y = dh[r, c], grad_x[r, c], grad_y[r, c]
            if not (np.isfinite(d) and np.isfinite(x) and np.isfinite(y)):
                continue
            if halfwidth > 0:
                model = p0 * x + p1 * y - p2
                if not abs(d - model - centre) <= halfwidth:
                    continue
            row = (x, y, -1.0)
            for i in range(3):
                for j in range(3):
                    normal[b, i * 3 + j] += row[i] * row[j]
                rhs[b, i] += row[i] * d
            count[b] += 1


def _final_bootstrap(last: dict[str, Any], shape: tuple[int, int], seed: int) -> np.ndarray:
    """Block-bootstrap sigmas of the last Gauss–Newton increment, over the blocks of
    :func:`_block_ids` of ``shape``.  Each block's normal equations are summed straight
    from the grids (:func:`_gradient_block_equations`; on a large grid,
    :func:`demtool.compare.threads.threaded`, the even and the odd blocks on two
    threads): no sample arrays or design matrix (on a 4096² grid they were 2 s on one
    core and ~1 GB), the same sums and sigmas."""
    from demtool.compare.threads import both, threaded

    params = last["params"]
    side, block_rows, block_cols = _block_grid(shape)
    blocks = block_rows * block_cols
    normal, rhs = np.zeros((blocks, 9)), np.zeros((blocks, 3))
    count = np.zeros(blocks, dtype=np.int64)
    arguments = (last["dh"], last["grad_x"], last["grad_y"],
                 np.ascontiguousarray(last["usable"], dtype=np.bool_),
                 float(params[0]), float(params[1]), float(params[2]),
                 float(last["centre"]), float(last["halfwidth"]), side, block_cols)
    if threaded(last["dh"].size):
        both(lambda: _gradient_block_equations(*arguments, 0, 2, normal, rhs, count),
             lambda: _gradient_block_equations(*arguments, 1, 2, normal, rhs, count),
             on=True)
    else:
        _gradient_block_equations(*arguments, 0, 1, normal, rhs, count)
    present = count > 0
    return _replicate_blocks(normal[present], rhs[present], seed=seed)


def nuth_kaab(dem: np.ndarray, reference: np.ndarray, *, mask: np.ndarray | None = None,
              max_iterations: int = 30, tolerance_px: float = 1e-4,
              fit_sigma_px: float = 1.0, coarse_sigmas: tuple[float, ...] = (3.0,),
              max_step_px: float = 2.0, max_shift_fraction: float = 0.1,
              bootstrap: bool = True, seed: int = 0) -> ShiftResult:
    """Horizontal and vertical shift of a DEM to a reference (linearised Nuth & Kääb).

    Parameters
    ----------
    dem, reference : (H, W) float arrays, metres, NaN = invalid, on one grid
        The DEM to align and the reference.  Not modified.
    mask : (H, W) bool, optional
        True where pixels may be used (stable terrain).
    max_iterations : int
        Iterations per level of the coarse-to-fine schedule.
    tolerance_px : float
        Convergence: horizontal increment below this many pixels.
    fit_sigma_px : float
        Both DEMs are compared after Gaussian smoothing of this standard deviation
        (pixels), the DEM's shift being applied by the same convolution
        (:func:`demtool.compare.shifts.gaussian_shift`).  This removes the
        shift-dependent phase error of polynomial interpolators, which biases the
        estimate by 0.005–0.02 px on rough terrain, and damps noise.  At least 0.8
        (1 or more keeps the kernel practically band-limited).
    coarse_sigmas : tuple of float
        Larger smoothing (pixels) for coarse levels run first; widens the capture range
        to several pixels.
    max_step_px : float
        Largest horizontal increment per iteration (a trust region).
    max_shift_fraction : float
        A shift beyond this fraction of the grid's shorter side, or no convergence with
        a last step above 0.01 px, is a divergence (ProcessingError).
    bootstrap : bool
        Estimate the uncertainty by a block bootstrap too (the reported sigma is the
        larger of bootstrap and formal values).
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    ShiftResult
        The total shift to add to the DEM, with its one-sigma uncertainty.

    Raises
    ------
    ProcessingError
        Fewer than 100 common valid pixels, or divergence (see ``max_shift_fraction``).

    Notes
    -----
    Model (Nuth & Kääb 2011, eq. 2–3, before the division by the slope): a DEM that is
    the reference displaced by ``−t`` and offset by ``−c`` differs from it by
    ``dh = z_dem − z_ref ≈ t · ∇z_ref − c``.  Each iteration solves this for the
    increment ``(δx, δy, δz)`` over all valid pixels (with one pass of 4·NMAD outlier
    rejection), shifts the DEM by the accumulated shift (Gaussian-smoothed, as the
    reference) and refits.
    """
    usable = _check_pair(dem, reference, mask)
    if int((usable & np.isfinite(dem)).sum()) < MIN_PIXELS:
        raise ProcessingError(f"fewer than {MIN_PIXELS} common valid pixels for Nuth & Kääb")
    shift = np.zeros(3)
    shift[2] = float(np.nanmedian(reference[usable] - dem[usable]))
    total_iterations = 0
    if not fit_sigma_px >= 0.8:
        raise ValueError(f"fit_sigma_px must be at least 0.8 px, got {fit_sigma_px}")
    for sigma_px in coarse_sigmas:
        shift, its, _, _ = _gradient_fit(dem, reference, usable, shift, sigma_px=sigma_px,
                                         max_iterations=max_iterations,
                                         tolerance_px=max(tolerance_px, 1e-2),
                                         max_step_px=max_step_px)
        total_iterations += its
    shift, its, converged, last = _gradient_fit(dem, reference, usable, shift,
                                                sigma_px=fit_sigma_px,
                                                max_iterations=max_iterations,
                                                tolerance_px=tolerance_px,
                                                max_step_px=max_step_px)
    total_iterations += its
    limit = max_shift_fraction * min(dem.shape)
    size = float(np.hypot(shift[0], shift[1]))
    if not np.isfinite(size) or size > limit or (not converged and last["step"] > 0.01):
        raise ProcessingError(
            f"Nuth & Kääb diverged (shift {shift[0]:.2f}, {shift[1]:.2f} px after "
            f"{total_iterations} iterations, last step {last['step']:.3f} px; at most "
            f"{limit:.0f} px accepted): the DEMs do not match here (another frame? no "
            "common relief?)")
    sigma = last["sigma"].copy()
    if bootstrap and np.all(np.isfinite(sigma)):
        sigma = np.fmax(sigma, _final_bootstrap(last, dem.shape, seed))
    if not converged:
        log.warning("Nuth & Kääb did not converge in %d iterations (last shift %.3f, %.3f px)",
                    max_iterations, shift[0], shift[1])
    return ShiftResult(float(shift[0]), float(shift[1]), float(shift[2]), float(sigma[0]),
                       float(sigma[1]), float(sigma[2]), total_iterations, converged,
                       int(last["count"]))
