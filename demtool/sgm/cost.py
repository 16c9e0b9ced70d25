"""Matching costs of semi-global matching: census, mutual information, absolute difference.

The cost ``C[y, x, k]`` (uint16) is that of matching the left pixel (x, y) with the
right pixel (x − d, y), d = ``min_disparity + k`` (demtool's disparity convention,
``x_right = x_left − d``).  Every cost is first computed per pixel and then summed
over a small ``window`` (a box filter, as OpenCV's StereoSGBM does with
``blockSize``), which makes it robust on weakly textured, noisy planetary images where
a pixelwise cost is not.  The SGM sweeps compute C one image row at a time
(:func:`advance_window`) and never hold the volume.  The MI cost table itself is in
:mod:`demtool.sgm.mutual_information` (re-exported here).

Invalid correspondences never match: where the right pixel is NaN in the input or
falls outside the image the pixelwise cost is that of a random match (half the
maximum, :func:`unmatched_cost`) and a disparity that wins there comes out NaN; where
the left pixel is NaN the cost is 0 for every disparity (neutral: the path costs carry
the smoothness term across it, and the output is NaN there anyway).

References
----------
Zabih, R. & Woodfill, J. (1994), Non-parametric local transforms for computing
visual correspondence, ECCV, 151–158 (census transform).
Kim, J., Kolmogorov, V. & Zabih, R. (2003), Visual correspondence using energy
minimization and mutual information, ICCV, 1033–1040 (Taylor expansion of MI).
Hirschmüller, H. (2008), Stereo processing by semiglobal matching and mutual
information, IEEE TPAMI 30(2), 328–341, §3.1.2 (eqs. 5–12, MI matching cost).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numba.core import types
from numba.extending import intrinsic

from demtool.sgm import extremes
from demtool.sgm.mutual_information import (  # noqa: F401  (part of this module's API)
    MI_MAX_NATS,
    MI_UNITS_PER_NAT,
    gaussian_matrix,
    mi_cost_table,
    mutual_information_table,
)


@intrinsic
def _popcount(typingctx, value):
    """Number of set bits of an integer (LLVM ``ctpop``: one instruction on x86-64, and
    vectorised as VPOPCNTD/Q where the CPU has them)."""
    if not isinstance(value, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        return builder.ctpop(args[0])

    return value(value), codegen


# --------------------------------------------------------------------------------------
# Image preparation
# --------------------------------------------------------------------------------------


def fill_invalid(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Replace invalid pixels by the nearest valid one (so windows near NaN stay finite).

    Parameters
    ----------
    image : (H, W) float array
    valid : (H, W) bool, True where ``image`` is usable

    Returns
    -------
    (H, W) float32; ``image`` itself when it is float32 and all valid, else a new array.
    """
    out = np.asarray(image, dtype=np.float32)
    if valid.all():
        return out
    from scipy import ndimage  # only here: its import costs about a second

    _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return out[rows, cols]


@njit(nogil=True, cache=True)
def _horizontal_sobel(image, valid, out):
    height, width = image.shape
    for y in range(height):
        above, below = max(y - 1, 0), min(y + 1, height - 1)  # mode "reflect": x[-1] = x[0]
        for x in range(width):
            if not valid[y, x]:
                out[y, x] = np.nan
                continue
            left, right = max(x - 1, 0), min(x + 1, width - 1)
            # scipy's correlate1d: [-1, 0, 1] as x·0 + (x[i−1] − x[i+1])·(−1), then
            # [1, 2, 1] as g·2 + (g[i−1] + g[i+1])·1, each rounded to float64 in turn
            g_above = (0.0 * np.float64(image[above, x])
                       - (np.float64(image[above, left]) - np.float64(image[above, right])))
            g_here = (0.0 * np.float64(image[y, x])
                      - (np.float64(image[y, left]) - np.float64(image[y, right])))
            g_below = (0.0 * np.float64(image[below, x])
                       - (np.float64(image[below, left]) - np.float64(image[below, right])))
            out[y, x] = np.float32(g_here * 2.0 + (g_above + g_below))


def horizontal_sobel(image: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Horizontal Sobel gradient (d/dx, smoothed [1, 2, 1] down the columns).

    The same values as ``scipy.ndimage.sobel(image.astype(np.float64), axis=1)`` (mode
    "reflect") rounded to float32, in one pass without the float64 images.

    Parameters
    ----------
    image : (H, W) float
        Finite everywhere (fill invalid pixels first: :func:`fill_invalid`).
    valid : (H, W) bool

    Returns
    -------
    (H, W) float32, grey levels per pixel; NaN where not ``valid``.
    """
    out = np.empty(image.shape, dtype=np.float32)
    _horizontal_sobel(np.ascontiguousarray(image), np.ascontiguousarray(valid), out)
    return out


def robust_range(images: list[np.ndarray], masks: list[np.ndarray],
                 percentiles: tuple[float, float] = (0.5, 99.5)) -> tuple[float, float]:
    """Low and high percentiles of the valid pixels of one or more images (a robust stretch)."""
    parts = [np.asarray(i).ravel() if m.all() else np.asarray(i)[m]
             for i, m in zip(images, masks, strict=True)]
    values = parts[0] if len(parts) == 1 else np.concatenate(parts)
    low, high = extremes.percentiles(values, percentiles)  # np.percentile's, faster
    if not high > low:
        high = low + 1.0
    return float(low), float(high)


@njit(nogil=True, cache=True)
def _quantize(image, low, scale, top, out):
    flat_in = image.ravel()
    flat_out = out.ravel()
    for i in range(flat_in.size):
        flat_out[i] = np.uint8(min(max(np.rint((flat_in[i] - low) * scale), 0.0), top))


def quantize(image: np.ndarray, valid: np.ndarray, levels: int,
             value_range: tuple[float, float] | None = None) -> np.ndarray:
    """Quantise an image to integer grey levels ``0 .. levels − 1`` by a robust linear stretch.

    Parameters
    ----------
    image : (H, W) float array, any scale (e.g. 12-bit DN), NaN allowed
    valid : (H, W) bool, True where ``image`` is usable
    levels : int, at most 256
    value_range : (low, high), optional
        Values mapped to 0 and ``levels − 1``; default: the 0.5 and 99.5 percentiles
        of the valid pixels (values beyond are clipped).

    Returns
    -------
    (H, W) uint8; invalid pixels get the level of their nearest valid neighbour.
    """
    low, high = value_range if value_range is not None else robust_range([image], [valid])
    filled = np.ascontiguousarray(fill_invalid(image, valid))
    out = np.empty(filled.shape, dtype=np.uint8)
    _quantize(filled, np.float32(low), np.float32((levels - 1) / (high - low)),
              np.float32(levels - 1), out)
    return out


@njit(nogil=True, cache=True)
def _census(padded, radius_y, radius_x, out):
    """Census codes, one image row at a time and one neighbour at a time along the row
    (so the loop over x vectorises)."""
    height, width = out.shape
    for y in range(height):
        for x in range(width):
            out[y, x] = 0
        for dy in range(2 * radius_y + 1):
            for dx in range(2 * radius_x + 1):
                if dy == radius_y and dx == radius_x:
                    continue
                for x in range(width):
                    darker = padded[y + dy, x + dx] < padded[y + radius_y, x + radius_x]
                    out[y, x] = (out[y, x] << np.uint64(1)) | np.uint64(darker)


def census_transform(image: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    """Census transform: one bit per neighbour, set where it is darker than the centre.

    Zabih & Woodfill (1994).  Borders replicate the edge pixels.

    Parameters
    ----------
    image : (H, W) float array without NaN (see :func:`fill_invalid`)
    window : (rows, columns), odd sizes with rows × columns − 1 ≤ 64 (5×5, 9×7, ...)

    Returns
    -------
    (H, W) bit strings: uint32 for windows of at most 32 bits (5×5: twice as many
    Hamming distances per vector instruction), else uint64.
    """
    rows, cols = window
    if rows % 2 == 0 or cols % 2 == 0 or rows * cols - 1 > 64:
        raise ValueError(f"census window {rows}x{cols}: sizes must be odd with at most 64 bits")
    out = np.empty(image.shape, dtype=np.uint32 if rows * cols - 1 <= 32 else np.uint64)
    padded = np.pad(np.asarray(image, dtype=np.float32), ((rows // 2,), (cols // 2,)), mode="edge")
    _census(padded, rows // 2, cols // 2, out)
    return out


def absolute_difference_table(levels: int, truncation: int) -> np.ndarray:
    """Pixel cost ``min(|i − k|, truncation)`` of every grey-level pair, (levels, levels) uint16."""
    grey = np.arange(levels)
    return np.minimum(np.abs(grey[:, None] - grey[None, :]), truncation).astype(np.uint16)


# --------------------------------------------------------------------------------------
# Windowed cost rows
# --------------------------------------------------------------------------------------
#
# The kernels take the pixelwise cost as one tuple ``source`` (see
# :meth:`PixelCost.kernel_source`): (kind, left codes, right codes, left levels, right
# levels, table, volume, left valid, right valid, min_disparity, unmatched cost,
# truncation), with kind 0 = census codes, 1 = grey levels through a cost table, 2 = a
# given volume of pixel costs (``volume[y]``, used to aggregate an arbitrary cost
# volume), 3 = the truncated absolute difference of grey levels, computed (truncation).
# The slots a kind does not use are None, so that numba compiles every kernel that takes
# a ``source`` once per kind, with only that kind's row kernel: :func:`_pixel_cost_row`
# branches on the slots being None, which numba resolves before typing (a fresh
# install's compile of the sweep kernel, which held all four, was 3-4 CPU s longer).

KIND_CENSUS, KIND_TABLE, KIND_VOLUME, KIND_ABSOLUTE_DIFFERENCE = 0, 1, 2, 3


@njit(nogil=True, cache=True)
def _disparity_span(x, min_disparity, width, n_disp):
    """Disparity indices k_lo <= k < k_hi whose right pixel x − d lies inside the image."""
    k_hi = max(0, min(n_disp, x - min_disparity + 1))
    k_lo = min(k_hi, max(0, x - min_disparity - width + 1))
    return k_lo, k_hi


# The row kernels below are separate functions with one simple loop nest each: merged
# into one loop over x (with the fills and the right-image mask), LLVM vectorised the
# Hamming distances half as well.  Inside [k_lo, k_hi) the right pixel of k = k_lo + i
# is x − d = start − i: an unsigned index (>= 0 there), so numba adds no negative-index
# wraparound, and a loop counted from 0, so LLVM sees the reversed loads as consecutive.
# The census row reads a reversed copy of the right row forwards instead (no lane
# reversal per vector: 40 -> 31 ns per pixel at 128 disparities).

@njit(nogil=True, cache=True)
def _census_row(left_codes, right_codes, left_valid, y, min_disparity, invalid_cost, out):
    width, n_disp = out.shape
    # the right row reversed, so that the disparities of a left pixel read it forwards
    reverse = np.empty(width, dtype=right_codes.dtype)
    for x in range(width):
        reverse[x] = right_codes[y, width - 1 - x]
    for x in range(width):
        k_lo, k_hi = _disparity_span(x, min_disparity, width, n_disp)
        first = width - 1 - (x - min_disparity - k_lo)
        code = left_codes[y, x]
        for i in range(k_hi - k_lo):
            out[x, k_lo + i] = np.uint16(_popcount(code ^ reverse[np.uint64(first + i)]))
    _fill_outside(left_valid, y, min_disparity, invalid_cost, out)


@njit(nogil=True, cache=True)
def _table_row(left_levels, right_levels, table, left_valid, y, min_disparity, invalid_cost,
               out):
    width, n_disp = out.shape
    for x in range(width):
        k_lo, k_hi = _disparity_span(x, min_disparity, width, n_disp)
        start = x - min_disparity - k_lo
        level = left_levels[y, x]
        for i in range(k_hi - k_lo):
            out[x, k_lo + i] = table[level, right_levels[y, np.uint64(start - i)]]
    _fill_outside(left_valid, y, min_disparity, invalid_cost, out)


@njit(nogil=True, cache=True)
def _absolute_difference_row(left_levels, right_levels, truncation, left_valid, y,
                             min_disparity, invalid_cost, out):
    """``min(|left − right|, truncation)``: the values of :func:`absolute_difference_table`,
    computed in int16 lanes from a reversed copy of the right row (as :func:`_census_row`)
    instead of one table load per cell (8 against 56 ns per pixel at 128 disparities)."""
    width, n_disp = out.shape
    reverse = np.empty(width, dtype=np.int16)
    for x in range(width):
        reverse[x] = right_levels[y, width - 1 - x]
    limit = np.int16(truncation)
    for x in range(width):
        k_lo, k_hi = _disparity_span(x, min_disparity, width, n_disp)
        first = width - 1 - (x - min_disparity - k_lo)
        level = np.int16(left_levels[y, x])
        for i in range(k_hi - k_lo):
            step = np.int16(level - reverse[np.uint64(first + i)])
            out[x, k_lo + i] = np.uint16(min(abs(step), limit))
    _fill_outside(left_valid, y, min_disparity, invalid_cost, out)


@njit(nogil=True, cache=True)
def _fill_outside(left_valid, y, min_disparity, invalid_cost, out):
    """Unmatched cost where x − d leaves the image; 0 (neutral) for invalid left pixels."""
    width, n_disp = out.shape
    for x in range(width):
        if not left_valid[y, x]:
            for k in range(n_disp):
                out[x, k] = 0
            continue
        k_lo, k_hi = _disparity_span(x, min_disparity, width, n_disp)
        for k in range(k_lo):
            out[x, k] = invalid_cost
        for k in range(k_hi, n_disp):
            out[x, k] = invalid_cost


@njit(nogil=True, cache=True)
def _mask_right_invalid(left_valid, right_valid, y, min_disparity, invalid_cost, out):
    """Unmatched cost where the right pixel x − d is invalid (NaN in the input)."""
    width, n_disp = out.shape
    for x in range(width):
        if not left_valid[y, x]:
            continue
        k_lo, k_hi = _disparity_span(x, min_disparity, width, n_disp)
        start = x - min_disparity - k_lo
        for i in range(k_hi - k_lo):
            if not right_valid[y, np.uint64(start - i)]:
                out[x, k_lo + i] = invalid_cost


@njit(nogil=True, cache=True)
def _pixel_cost_row(y, out, kind, left_codes, right_codes, left_levels, right_levels, table,
                    volume, left_valid, right_valid, min_disparity, invalid_cost, truncation):
    """Pixelwise costs of image row ``y`` into ``out`` (W, D) uint16; the other arguments
    are a ``source`` tuple's slots (``_pixel_cost_row(y, out, *source)``), of which the
    kind's own one is not None (the others' branches are dropped before typing)."""
    width, n_disp = out.shape
    if volume is not None:
        for x in range(width):
            for k in range(n_disp):
                out[x, k] = volume[y, x, k]
        return
    if left_codes is not None:
        _census_row(left_codes, right_codes, left_valid, y, min_disparity, invalid_cost, out)
    if truncation is not None:
        _absolute_difference_row(left_levels, right_levels, truncation, left_valid, y,
                                 min_disparity, invalid_cost, out)
    if table is not None:
        _table_row(left_levels, right_levels, table, left_valid, y, min_disparity,
                   invalid_cost, out)
    for x in range(width):
        if not right_valid[y, x]:
            _mask_right_invalid(left_valid, right_valid, y, min_disparity, invalid_cost, out)
            break


@njit(nogil=True, cache=True)
def _push_window_row(pixel, radius, ring, slot, running):
    """Box-sum a row of pixel costs along x (edges replicated) into ``ring[slot]`` and
    update the vertical running sum: ``running += new − ring[slot]`` (the row it replaces).

    Sums wrap modulo 2¹⁶ while running, which is exact because every window sum fits
    uint16 (checked by the callers), so the loops vectorise 16 lanes wide.
    """
    width, n_disp = pixel.shape
    acc = np.zeros(n_disp, dtype=np.uint16)
    for j in range(-radius, radius + 1):
        src = min(max(j, 0), width - 1)
        for k in range(n_disp):
            acc[k] += pixel[src, k]
    for x in range(width):
        add = min(x + radius + 1, width - 1)
        sub = max(x - radius, 0)
        for k in range(n_disp):
            new = acc[k]
            running[x, k] += new - ring[slot, x, k]
            ring[slot, x, k] = new
            acc[k] = acc[k] + pixel[add, k] - pixel[sub, k]


@njit(nogil=True, cache=True)
def advance_window(source, y, sign, radius, ring, running, pixel, window_state):
    """Make ``running`` (W, D) the window-summed cost of image row ``y``.

    A sweep calls this for consecutive rows ``y`` stepping by ``sign`` (+1 down, −1
    up).  ``ring`` (2·radius + 1, W, D) uint16 keeps the horizontally box-summed pixel
    rows of the window, ``running`` their sum; ``window_state`` (int64[2]) holds the
    ring slot of the row to drop next and whether the ring is filled (0 = start a new
    sweep at ``y``).  Rows beyond the image replicate the edge rows.  Each call
    computes one new row of pixel costs (``pixel``, scratch (W, D) uint16), so the
    window costs O(1) per cell whatever its size.
    """
    height = source[7].shape[0]
    size = 2 * radius + 1
    starting = window_state[1] == 0
    if starting:
        # loops, not ``ring[:] = 0``: slice assignment compiles a second longer
        for x in range(running.shape[0]):
            for k in range(running.shape[1]):
                running[x, k] = 0
                for j in range(size):
                    ring[j, x, k] = 0
    # the window's rows j = 0 … size − 1 when starting, else its newest, j = size − 1
    # (one call of each kernel: LLVM inlines a callee at every call site, and the
    # sweep kernel then compiles each copy again)
    count = size if starting else 1
    for i in range(count):
        j = size - count + i
        yy = min(max(y + sign * (j - radius), 0), height - 1)
        _pixel_cost_row(yy, pixel, *source)
        _push_window_row(pixel, radius, ring, j if starting else window_state[0], running)
    window_state[0] = 0 if starting else (window_state[0] + 1) % size
    window_state[1] = 1


@njit(nogil=True, cache=True)
def _window_rows(source, radius, row_start, out):
    """Window-summed costs of rows ``row_start .. row_start + len(out)`` (top-down)."""
    n_rows, width, n_disp = out.shape
    ring = np.zeros((2 * radius + 1, width, n_disp), dtype=np.uint16)
    running = np.zeros((width, n_disp), dtype=np.uint16)
    pixel = np.empty((width, n_disp), dtype=np.uint16)
    window_state = np.zeros(2, dtype=np.int64)
    for i in range(n_rows):
        advance_window(source, row_start + i, 1, radius, ring, running, pixel, window_state)
        out[i] = running


@dataclass(frozen=True)
class PixelCost:
    """What the pixelwise cost compares: census codes, or grey levels and a cost table.

    Attributes
    ----------
    name : str
        "census", "mi" or "ad" (for messages and reports).
    left, right : (H, W) uint32/uint64 census codes, or (H, W) uint8 grey levels
    table : (L, L) uint16
        Cost of each (left level, right level) pair; unused (1×1) for census.
    max_cost : int
        The largest pixel cost.
    truncation : int
        For an absolute difference (:func:`absolute_difference_pixel_cost`): the
        truncation of ``table``, whose values the kernels then compute instead of
        looking up; −1 otherwise.
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    table: np.ndarray
    max_cost: int
    truncation: int = -1

    @property
    def is_census(self) -> bool:
        return self.name == "census"

    def kernel_source(self, left_valid: np.ndarray, right_valid: np.ndarray,
                      min_disparity: int, unmatched_fraction: float = 0.5) -> tuple:
        """The tuple the numba kernels take as ``source`` (see :func:`advance_window`).

        Parameters
        ----------
        left_valid, right_valid : (H, W) bool, True where the input pixel is finite
        min_disparity : int, disparity of index 0
        unmatched_fraction : float
            Pixel cost of a correspondence outside the right image or on a NaN pixel,
            as a fraction of :attr:`max_cost` (see :func:`unmatched_cost`).
        """
        if self.is_census:
            kind, codes, levels, table, truncation = (KIND_CENSUS, (self.left, self.right),
                                                      (None, None), None, None)
        elif self.truncation >= 0:
            kind, codes, levels, table, truncation = (
                KIND_ABSOLUTE_DIFFERENCE, (None, None), (self.left, self.right), None,
                np.uint16(self.truncation))
        else:
            kind, codes, levels, table, truncation = (KIND_TABLE, (None, None),
                                                      (self.left, self.right), self.table,
                                                      None)
        return (kind, *codes, *levels, table, None,
                np.ascontiguousarray(left_valid, dtype=np.bool_),
                np.ascontiguousarray(right_valid, dtype=np.bool_), int(min_disparity),
                np.uint16(unmatched_cost(self, unmatched_fraction)), truncation)


def census_pixel_cost(left: np.ndarray, right: np.ndarray, window: tuple[int, int], *,
                      workers: int = 1) -> PixelCost:
    """Census pixel cost (Hamming distance of the census codes) of a NaN-filled pair.

    With ``workers`` > 1 the two transforms run in two threads.
    """
    bits = window[0] * window[1] - 1
    if workers > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=1) as pool:
            future = pool.submit(census_transform, right, window)
            codes_left = census_transform(left, window)
            codes_right = future.result()
    else:
        codes_left, codes_right = census_transform(left, window), census_transform(right, window)
    return PixelCost("census", codes_left, codes_right, np.zeros((1, 1), dtype=np.uint16), bits)


def table_pixel_cost(name: str, left_levels: np.ndarray, right_levels: np.ndarray,
                     table: np.ndarray) -> PixelCost:
    """Table pixel cost (MI or absolute difference) of a pair of grey-level images."""
    table = np.ascontiguousarray(table, dtype=np.uint16)
    return PixelCost(name, left_levels, right_levels, table, int(table.max()))


def absolute_difference_pixel_cost(name: str, left_levels: np.ndarray,
                                   right_levels: np.ndarray, *, levels: int,
                                   truncation: int) -> PixelCost:
    """Truncated absolute difference ``min(|i − k|, truncation)`` of grey levels 0 …
    ``levels`` − 1 (:func:`absolute_difference_table`; the kernels compute it)."""
    table = absolute_difference_table(levels, truncation)
    return PixelCost(name, left_levels, right_levels, table, int(table.max()),
                     int(truncation))


def unmatched_cost(pixel_cost: PixelCost, fraction: float = 0.5) -> int:
    """Pixel cost of a correspondence that does not exist (outside or NaN in the right image).

    About the cost of a random, wrong match (half the census bits differ), so that
    such disparities neither win by default nor repel the smoothness term: a left
    pixel whose true match left the right image (the left border band, a NaN area)
    takes its neighbours' disparity, points outside and comes out NaN, instead of
    snapping to the nearest disparity that stays inside.
    """
    return int(round(fraction * pixel_cost.max_cost))


def volume_source(volume: np.ndarray) -> tuple:
    """The kernels' ``source`` tuple for a given (H, W, D) uint16 volume of pixel costs."""
    valid = np.ones(volume.shape[:2], dtype=np.bool_)
    return (KIND_VOLUME, None, None, None, None, None,
            np.ascontiguousarray(volume, dtype=np.uint16), valid, valid, 0, np.uint16(0), None)


def windowed_cost_volume(pixel_cost: PixelCost, left_valid: np.ndarray,
                         right_valid: np.ndarray, *, min_disparity: int,
                         num_disparities: int, window: int, rows: tuple[int, int],
                         unmatched_fraction: float = 0.5) -> np.ndarray:
    """Cost volume of image rows ``rows[0] .. rows[1]``, summed over a square window.

    The SGM sweeps compute these rows on the fly (:func:`advance_window`) and never
    hold the volume; this function is for inspection and tests.

    Parameters
    ----------
    pixel_cost : PixelCost
        The pixelwise cost (census, MI or absolute difference).
    left_valid, right_valid : (H, W) bool, True where the input pixel is finite
    min_disparity, num_disparities : int
        The volume covers d = min_disparity .. min_disparity + num_disparities − 1.
    window : int, odd
        Side of the square window the pixel costs are summed over (1 = pixelwise).
    rows : (start, stop)
        The image rows to compute; windows reach beyond them into the image.
    unmatched_fraction : float
        Pixel cost of a correspondence outside the right image or on a NaN pixel, as
        a fraction of ``pixel_cost.max_cost`` (see :func:`unmatched_cost`).

    Returns
    -------
    (stop − start, W, num_disparities) uint16, the cost C[y − start, x, k]; at most
    ``window² · pixel_cost.max_cost``.
    """
    start, stop = rows
    out = np.empty((stop - start, left_valid.shape[1], num_disparities), dtype=np.uint16)
    source = pixel_cost.kernel_source(left_valid, right_valid, min_disparity,
                                      unmatched_fraction)
    _window_rows(source, window // 2, int(start), out)
    return out
