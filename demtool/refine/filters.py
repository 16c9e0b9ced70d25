"""Low-pass filters and the DCT-domain operators of the shape-from-shading solver.

All filters use half-sample symmetric ("reflect") boundaries, the boundary condition
that the type-II discrete cosine transform (DCT) diagonalises.  The Gaussian low-pass
f(·) of the energy (Grumpe & Wöhler 2014) and the Neumann Laplacian of the height
update are therefore both diagonal in the DCT domain, which makes the height update
an exact O(N log N) solve and keeps the borders free of wrap-around jumps
(Simchony, Chellappa & Shao 1990, *Direct analytical methods for solving Poisson
equations in computer vision problems*, IEEE PAMI 12(5), 435–446).

Also here: the central-difference gradient G of the integrability term and its
adjoint (numpy references of the compiled kernels in :mod:`demtool.refine.kernels`),
the border taper, Egrad's block low-pass, and the exact sliding-rank median filter.
"""

from __future__ import annotations

import functools

import numba as nb
import numpy as np
import scipy.fft as sfft

#: Threads used by scipy.fft (None: as many as the row kernels of the calling thread,
#: ``numba.get_num_threads()`` within :func:`demtool.tiling.tasks.usable_threads` — every
#: core untiled, the worker's share in a tile or under ``--workers``; -1: all cores).  The
#: transform's numbers do not depend on it.
FFT_WORKERS: int | None = None


def _fft_workers() -> int:
    if FFT_WORKERS is not None:
        return FFT_WORKERS
    from demtool.tiling.tasks import usable_threads

    return max(1, min(nb.get_num_threads(), usable_threads()))


def dct2(array: np.ndarray) -> np.ndarray:
    """Orthonormal 2-D DCT-II of ``array`` (dtype kept: float32 stays float32)."""
    return sfft.dctn(array, type=2, norm="ortho", workers=_fft_workers())


def idct2(coefficients: np.ndarray) -> np.ndarray:
    """Inverse of :func:`dct2`."""
    return sfft.idctn(coefficients, type=2, norm="ortho", workers=_fft_workers())


def dct_frequencies(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Angular frequencies (rad/pixel) of the DCT-II coefficients along rows and columns.

    Returns
    -------
    omega_row : (H, 1) float64
        ``π l / H`` for coefficient row ``l``.
    omega_col : (1, W) float64
        ``π k / W`` for coefficient column ``k``.
    """
    height, width = shape
    omega_row = (np.pi * np.arange(height) / height)[:, np.newaxis]
    omega_col = (np.pi * np.arange(width) / width)[np.newaxis, :]
    return omega_row, omega_col


@functools.lru_cache(maxsize=8)
def gaussian_transfer(shape: tuple[int, int], sigma: float) -> np.ndarray:
    """DCT-domain transfer function of a Gaussian low-pass of std ``sigma`` pixels.

    ``g = exp(−σ² (ω_row² + ω_col²) / 2)``, the Fourier transform of the Gaussian
    kernel sampled at the DCT frequencies (separable: an outer product).

    Returns
    -------
    (H, W) float32, read-only (cached per shape and σ)
    """
    from demtool.refine.rowwork import on_row_blocks

    omega_row, omega_col = dct_frequencies(tuple(shape))
    along_rows = np.exp(-0.5 * sigma**2 * omega_row**2)
    along_cols = np.exp(-0.5 * sigma**2 * omega_col**2)
    transfer = np.empty(tuple(shape), dtype=np.float32)

    def part(start: int, stop: int) -> None:  # the outer product on every core
        transfer[start:stop] = along_rows[start:stop] * along_cols

    on_row_blocks(part, *transfer.shape)
    transfer.flags.writeable = False
    return transfer


def neumann_laplacian_eigenvalues(shape: tuple[int, int], aspect: float = 1.0) -> np.ndarray:
    """Eigenvalues of ``DxᵀDx + DyᵀDy`` (forward differences, Neumann boundaries).

    ``λ = (2 − 2 cos ω_col) + aspect² (2 − 2 cos ω_row)``; ``aspect = dx / dy`` scales the
    row differences when the pixel spacings differ (Simchony et al. 1990, eq. 20).

    Returns
    -------
    (H, W) float32
        Zero for the constant (0, 0) coefficient.
    """
    from demtool.refine.rowwork import on_row_blocks

    omega_row, omega_col = dct_frequencies(shape)
    along_cols = 2.0 - 2.0 * np.cos(omega_col)
    along_rows = aspect**2 * (2.0 - 2.0 * np.cos(omega_row))
    eigen = np.empty(tuple(shape), dtype=np.float32)

    def part(start: int, stop: int) -> None:  # the outer sum on every core
        eigen[start:stop] = along_cols + along_rows[start:stop]

    on_row_blocks(part, *eigen.shape)
    return eigen


def gaussian_lowpass(array: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian low-pass of a finite 2-D array with reflect boundaries, in the DCT domain.

    Parameters
    ----------
    array : (H, W) float
        Values without NaN.
    sigma : float
        Standard deviation in pixels; 0 returns a copy.

    Returns
    -------
    (H, W) float32
    """
    values = np.asarray(array, dtype=np.float32)
    if sigma <= 0:
        return values.copy()
    from demtool.tiling.rows import on_row_parts

    coefficients = dct2(values)
    transfer = gaussian_transfer(values.shape, float(sigma))
    # the product in place, rows on every core (the DCTs are pocketfft's threads)
    on_row_parts(lambda start, stop: np.multiply(coefficients[start:stop],
                                                 transfer[start:stop],
                                                 out=coefficients[start:stop]),
                 values.shape[0])
    return idct2(coefficients)


def masked_gaussian_lowpass(array: np.ndarray, weight: np.ndarray, sigma: float,
                            floor: float = 1e-3) -> np.ndarray:
    """Normalised convolution: ``f(w·a) / f(w)``, the low-pass of ``a`` where ``w`` > 0.

    Pixels with ``w = 0`` (shadows, nodata) take the weighted mean of their
    neighbourhood; where ``f(w)`` falls below ``floor`` (no valid pixel within a few σ)
    the global weighted mean is used.

    Parameters
    ----------
    array : (H, W) float
        Values; ignored (may be NaN) where ``weight`` is 0.
    weight : (H, W) float or bool
        Non-negative weights.
    sigma : float
        Standard deviation in pixels.

    Returns
    -------
    (H, W) float32
    """
    w = np.ascontiguousarray(weight, dtype=np.float32)
    weighted = np.empty(w.shape, dtype=np.float32)
    _masked_product(np.ascontiguousarray(array, dtype=np.float32), w, weighted)
    total = float(w.sum())
    if total <= 0:
        raise ValueError("masked_gaussian_lowpass: the weight is zero everywhere")
    numerator = gaussian_lowpass(weighted, sigma)
    denominator = gaussian_lowpass(w, sigma)
    fallback = np.float32(float(weighted.sum()) / total)
    out = np.empty(w.shape, dtype=np.float32)
    _ratio_above(numerator, denominator, np.float32(floor), fallback, out)
    return out


def _masked_product(values: np.ndarray, weight: np.ndarray, out: np.ndarray) -> None:
    """``out = (values where weight > 0, else 0) · weight`` (float32, rows on every core:
    :func:`demtool.tiling.rows.on_row_parts`)."""
    from demtool.tiling.rows import on_row_parts

    on_row_parts(lambda start, stop: _masked_product_rows(values, weight, out, start, stop),
                 values.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _masked_product_rows(values, weight, out, start, stop):  # pragma: no cover - compiled
    width = values.shape[1]
    zero = np.float32(0.0)
    for r in range(start, stop):
        for c in range(width):
            w = weight[r, c]
            out[r, c] = (values[r, c] if w > 0 else zero) * w


def _ratio_above(numerator: np.ndarray, denominator: np.ndarray, floor: np.float32,
                 fallback: np.float32, out: np.ndarray) -> None:
    """``out = numerator / denominator`` where ``denominator > floor``, else ``fallback``."""
    from demtool.tiling.rows import on_row_parts

    on_row_parts(lambda start, stop: _ratio_above_rows(numerator, denominator, floor,
                                                       fallback, out, start, stop),
                 numerator.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _ratio_above_rows(numerator, denominator, floor, fallback, out, start,
                      stop):  # pragma: no cover - compiled
    width = numerator.shape[1]
    for r in range(start, stop):
        for c in range(width):
            d = denominator[r, c]
            out[r, c] = numerator[r, c] / d if d > floor else fallback


# --------------------------------------------------------------------------------------
# Difference operators (heights in pixel units, rows down, y up)
# --------------------------------------------------------------------------------------


def central_gradient(z: np.ndarray, aspect: float) -> tuple[np.ndarray, np.ndarray]:
    """G z: central differences with mirrored borders; ``aspect = dx / dy``.

    Equals :func:`demtool.refine.shading.slopes` of ``z · dx`` with spacing (dx, dy).
    """
    gx = np.empty_like(z)
    gx[:, 1:-1] = 0.5 * (z[:, 2:] - z[:, :-2])
    gx[:, 0] = 0.5 * (z[:, 1] - z[:, 0])
    gx[:, -1] = 0.5 * (z[:, -1] - z[:, -2])
    gy = np.empty_like(z)
    half = np.float32(-0.5 * aspect)  # y up: rows down
    gy[1:-1] = half * (z[2:] - z[:-2])
    gy[0] = half * (z[1] - z[0])
    gy[-1] = half * (z[-1] - z[-2])
    return gx, gy


def central_gradient_adjoint(ex: np.ndarray, ey: np.ndarray, aspect: float) -> np.ndarray:
    """Gᵀ (ex, ey), the adjoint of :func:`central_gradient`."""
    out = np.empty_like(ex)
    out[:, 1:-1] = 0.5 * (ex[:, :-2] - ex[:, 2:])
    out[:, 0] = -0.5 * (ex[:, 0] + ex[:, 1])
    out[:, -1] = 0.5 * (ex[:, -2] + ex[:, -1])
    half = np.float32(-0.5 * aspect)
    out[1:-1] += half * (ey[:-2] - ey[2:])
    out[0] += half * -(ey[0] + ey[1])
    out[-1] += half * (ey[-2] + ey[-1])
    return out


def border_taper(shape: tuple[int, int], width: float) -> np.ndarray:
    """Weight rising from 0 at the outermost pixels to 1 at ``width`` pixels (sin²).

    Returns
    -------
    (H, W) float32
    """
    height, width_px = shape
    if width <= 0:
        return np.ones(shape, dtype=np.float32)
    from demtool.refine.rowwork import on_row_blocks

    rows = np.arange(height)
    cols = np.arange(width_px)
    from_side = np.minimum(cols, width_px - 1 - cols)[None, :]
    taper = np.empty(shape, dtype=np.float32)

    def part(start: int, stop: int) -> None:  # rows on every core
        part_rows = rows[start:stop]
        distance = np.minimum(np.minimum(part_rows, height - 1 - part_rows)[:, None],
                              from_side)
        ramp = np.clip(distance / width, 0.0, 1.0)
        taper[start:stop] = np.sin(0.5 * np.pi * ramp) ** 2

    on_row_blocks(part, height, width_px)
    return taper


#: Egrad's low-pass runs on blocks of this many pixels per σ_f / 5 (σ_f = 21 px: 4 × 4).
_BLOCK_PER_SIGMA = 0.2


class BlockGaussianLowpass:
    """fᵀf of Egrad, evaluated on b × b block means (b ≈ σ_f / 5, dividing the grid).

    f here is the Gaussian of std σ_f / b (DCT domain, reflect borders) on the b × b
    block means: the box and the Gaussian together are a Gaussian of std
    sqrt(σ_f² + (b² − 1)/12) ≈ σ_f (21.03 px for σ_f = 21, b = 4) at the frequencies f
    passes, on b² times fewer samples.  ``apply(x, x0) = b² Aᵀ F² A (x − x0)`` (A the
    block mean, b² Aᵀ the replication) is the exact gradient of ``b² ‖F A (x − x0)‖²``,
    the Egrad that is reported, and its norm is at most 1, so the slope step's
    majoriser δ I stays valid.  b is the largest integer ≤ σ_f / 5 that divides both
    sides of the grid (1 — the plain DCT — when none does).
    """

    def __init__(self, shape: tuple[int, int], sigma: float) -> None:
        from demtool.refine import kernels  # numba kernels: compiled on first use

        self._kernels = kernels
        largest = int(max(1, min(sigma * _BLOCK_PER_SIGMA, min(shape) // 4)))
        self.block = next(b for b in range(largest, 0, -1)
                          if shape[0] % b == 0 and shape[1] % b == 0)
        self.coarse_shape = (shape[0] // self.block, shape[1] // self.block)
        self.transfer2 = gaussian_transfer(self.coarse_shape, sigma / self.block) ** 2
        self._coarse = np.empty(self.coarse_shape, dtype=np.float32)

    def apply(self, values: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """``b² Aᵀ F² A (values − reference)``, (H, W) float32."""
        self._kernels.block_mean(values, reference, self.block, self._coarse)
        smoothed = idct2(dct2(self._coarse) * self.transfer2).astype(np.float32)
        out = np.empty_like(values)
        self._kernels.block_replicate(smoothed, self.block, out)
        return out


# --------------------------------------------------------------------------------------
# Median filter (numba): the study's 15 px spike removal of the coarse DEM
# --------------------------------------------------------------------------------------

#
# A sliding-window rank structure (Huang, Yang & Tang 1979, on ranks instead of grey
# levels; two-level histogram as in Perreault & Hébert 2007): the values are replaced
# by their ranks in the whole padded grid (the positions of an argsort: every rank is
# unique and the median of the ranks is the rank of the median; equal values in either
# order have the same median, so the argsort need not be stable — introsort takes half
# the time of the stable sort, 0.35 vs 0.71 s on a 2062² grid), the window is a bitmap over
# the ranks plus counts per bin of 1024 ranks, and moving one column swaps 2 × size
# entries.  The median is found by walking the bin counts from the previous median's
# bin (it moves little) and counting the set bits inside the bin.  Exact, O(size) per
# pixel instead of O(size²) for a selection.

_BIN_SHIFT = 10  # 1024 ranks per bin = 16 words of 64 bits
_WORDS_PER_BIN = 1 << (_BIN_SHIFT - 6)


@nb.njit(cache=True, inline="always")
def _popcount(x: np.uint64) -> int:
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2))
                                                & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@nb.njit(cache=True, inline="always")
def _toggle(rank: int, sign: int, bitmap: np.ndarray, counts: np.ndarray) -> None:
    bitmap[rank >> 6] ^= np.uint64(1) << np.uint64(rank & 63)
    counts[rank >> _BIN_SHIFT] += sign


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _median_ranks(ranks: np.ndarray, sorted_values: np.ndarray, height: int, width: int,
                  size: int, bins: int) -> np.ndarray:  # pragma: no cover - compiled
    # serial: median_filter runs one strip per thread (a parallel=True loop here compiled
    # for 6 s in a fresh install and ran on one thread inside the strips anyway)
    out = np.empty((height, width), dtype=sorted_values.dtype)
    target = size * size // 2
    bitmap = np.zeros(bins * _WORDS_PER_BIN, dtype=np.uint64)  # emptied after each row
    counts = np.zeros(bins, dtype=np.int64)
    for r in range(height):
        for j in range(size):
            for i in range(size):
                _toggle(ranks[r + i, j], 1, bitmap, counts)
        pivot = 0  # bin of the median; ``below`` = entries in bins before it
        below = 0
        for c in range(width):
            if c > 0:
                for i in range(size):
                    old = ranks[r + i, c - 1]
                    _toggle(old, -1, bitmap, counts)
                    if (old >> _BIN_SHIFT) < pivot:
                        below -= 1
                    new = ranks[r + i, c + size - 1]
                    _toggle(new, 1, bitmap, counts)
                    if (new >> _BIN_SHIFT) < pivot:
                        below += 1
            while below > target:
                pivot -= 1
                below -= counts[pivot]
            while below + counts[pivot] <= target:
                below += counts[pivot]
                pivot += 1
            # the (target − below)-th set bit of the pivot bin
            remaining = target - below
            word_index = pivot * _WORDS_PER_BIN
            word = bitmap[word_index]
            bits = _popcount(word)
            while remaining >= bits:
                remaining -= bits
                word_index += 1
                word = bitmap[word_index]
                bits = _popcount(word)
            for _ in range(remaining):
                word &= word - np.uint64(1)
            lowest = (word & (~word + np.uint64(1))) - np.uint64(1)
            out[r, c] = sorted_values[word_index * 64 + _popcount(lowest)]
        for j in range(width - 1, width + size - 1):  # empty the window
            for i in range(size):
                _toggle(ranks[r + i, j], -1, bitmap, counts)
    return out


#: Rows of output at least per strip of :func:`median_filter` (below, one strip).
MEDIAN_STRIP_ROWS = 64


@nb.njit(cache=True, nogil=True)
def _ranks_of(order: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """The inverse permutation of ``order``: each element's rank."""
    ranks = np.empty(order.size, dtype=np.int64)
    for rank in range(order.size):
        ranks[order[rank]] = rank
    return ranks


def _median_of_strip(padded: np.ndarray, size: int) -> np.ndarray:
    """The median filter's output rows of a (padded) strip: ranks, then the sliding rank
    window (:func:`_median_ranks`)."""
    height, width = padded.shape[0] - size + 1, padded.shape[1] - size + 1
    order = np.argsort(padded, axis=None)  # numpy sorts without the GIL
    bins = (order.size >> _BIN_SHIFT) + 1
    return _median_ranks(_ranks_of(order).reshape(padded.shape), padded.ravel()[order],
                         height, width, size, bins)


def median_filter(array: np.ndarray, size: int) -> np.ndarray:
    """Square ``size`` × ``size`` median filter with reflect boundaries (numba, in strips).

    Equal to ``scipy.ndimage.median_filter(array, size, mode="reflect")`` for odd
    ``size``; O(size) work per pixel (sliding rank window, see above), about ten times
    faster than a per-pixel selection for the 15 px window of the NavCam study.

    On n threads (numba's count of the calling thread) the rows are cut into n strips,
    each ranked (sorted) and filtered on its own thread: the sort of one grid-wide rank
    order was the serial part.  A window's median is the same value whatever the ranks'
    extent (ranks order values; equal values have the same median either way), so the
    output does not depend on the strips.

    Parameters
    ----------
    array : (H, W) float
        Values without NaN.
    size : int
        Odd window size in pixels; 0 or 1 returns a float32 copy.

    Returns
    -------
    (H, W) float32
    """
    values = np.asarray(array, dtype=np.float32)
    if size <= 1:
        return values.copy()
    if size % 2 == 0:
        raise ValueError(f"median window must be odd, got {size}")
    padded = np.pad(values, size // 2, mode="symmetric")
    height = values.shape[0]
    strips = max(1, min(nb.get_num_threads(), height // MEDIAN_STRIP_ROWS))
    if strips == 1:
        return _median_of_strip(padded, size)
    from concurrent.futures import ThreadPoolExecutor

    bounds = [height * i // strips for i in range(strips + 1)]
    out = np.empty(values.shape, dtype=np.float32)

    def strip(i: int) -> None:
        nb.set_num_threads(1)  # this pool thread's kernels (numba's count is per thread)
        r0, r1 = bounds[i], bounds[i + 1]
        out[r0:r1] = _median_of_strip(padded[r0:r1 + size - 1], size)

    with ThreadPoolExecutor(strips) as pool:
        list(pool.map(strip, range(strips)))
    return out
