"""Disparity selection and post-processing of semi-global matching.

Winner-takes-all on the aggregated cost S, sub-pixel interpolation, the right
image's disparity from the same S (diagonal search, Hirschmüller 2008 §3.1.4), the
left–right consistency check, speckle removal and a NaN-aware median filter (the fill
of invalid pixels: :mod:`demtool.sgm.fill`), and :func:`in_halves`, which runs the
post-processing kernels in two threads.

Disparity convention: ``x_right = x_left − d`` in the left image's pixel frame,
float32 pixels, NaN = invalid.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit

from demtool.sgm.simd import best_two, right_minima
from demtool.tiling.rows import on_row_parts

SUBPIXEL_MODES = {"none": 0, "parabola": 1, "equiangular": 2}
#: Confidence :func:`select_row` gives a pixel the left–right check rejects as occluded
#: (the right view sees a nearer surface at its match); other invalid pixels get NaN.
OCCLUDED = -1.0


@njit(nogil=True, cache=True)
def _subpixel_offset(mode, minus, centre, plus):
    """Offset in (−0.5, 0.5] of the minimum of a curve sampled at −1, 0, +1."""
    if mode == 1:  # parabola through the three samples
        denominator = minus + plus - 2.0 * centre
        if denominator <= 0.0:
            return 0.0
        return 0.5 * (minus - plus) / denominator
    if mode == 2:  # equiangular (symmetric V) fit, Shimizu & Okutomi (2001)
        denominator = 2.0 * (max(minus, plus) - centre)
        if denominator <= 0.0:
            return 0.0
        return (minus - plus) / denominator
    return 0.0


@njit(nogil=True, cache=True)
def _right_disparities(srow, min_disparity, right_best, right_key):
    """Right image's WTA disparity index d_R(x_r) = argmin_k S(x_r + d_k, k) of one row.

    The diagonal of the left row's S: for every left pixel x the loop over k visits the
    right pixels x − d_k, all distinct, so it vectorises.  Each candidate is the key
    S·2¹⁶ + k (uint32), so one running minimum per right pixel (``right_key``, (W)
    uint32 scratch) keeps the lowest cost and, among equal costs, the smallest k.
    ``right_best`` (W) int16 gets k, or −1 where no disparity reaches the right pixel.
    """
    width, n_disp = srow.shape
    for xr in range(width):
        right_key[xr] = 0xFFFFFFFF
    right_minima(srow, right_key, min_disparity)
    for xr in range(width):
        key = right_key[xr]
        right_best[xr] = -1 if key == 0xFFFFFFFF else np.int16(key & np.uint32(0xFFFF))


@njit(nogil=True, cache=True)
def _best_two(srow, x):
    """:func:`demtool.sgm.simd.best_two` in plain loops (for D < 16)."""
    n_disp = srow.shape[1]
    # argmin as the minimum of the keys S·2¹⁶ + k: ties keep the smallest k
    best_key = np.uint32(0xFFFFFFFF)
    for k in range(n_disp):
        best_key = min(best_key, (np.uint32(srow[x, k]) << np.uint32(16)) | np.uint32(k))
    best = np.int64(best_key & np.uint32(0xFFFF))
    # the best cost at least two disparities away
    second = np.uint16(65535)
    for k in range(n_disp):
        value = srow[x, k]
        second = min(second, np.uint16(65535) if abs(k - best) <= 1 else value)
    return best, np.int64(best_key >> np.uint32(16)), np.int64(second)


@njit(nogil=True, cache=True)
def select_row(srow, y, min_disparity, mode, lr_threshold, left_valid, right_valid,
               right_best, right_key, disparity, confidence):
    """WTA, sub-pixel and LR check of one image row (see :func:`select_disparities`).

    ``srow`` (W, D) uint16 is the row's aggregated cost; ``y`` its image row (for the
    validity masks); ``right_best`` (W) int16 and ``right_key`` (W) uint32 are
    scratch; results go to ``disparity`` and ``confidence`` (W) float32.
    """
    width, n_disp = srow.shape
    if lr_threshold >= 0:
        _right_disparities(srow, min_disparity, right_best, right_key)
    for x in range(width):
        if n_disp >= 16:
            best, low, second = best_two(srow, x)
        else:
            best, low, second = _best_two(srow, x)
        d_int = min_disparity + best
        xr = x - d_int
        valid = left_valid[y, x] and xr >= 0 and xr < width and right_valid[y, xr]
        offset = 0.0
        if valid and best > 0 and best < n_disp - 1:
            offset = _subpixel_offset(mode, np.float64(srow[x, best - 1]), np.float64(low),
                                      np.float64(srow[x, best + 1]))
        if valid and lr_threshold >= 0:
            # the right pixels on either side of the sub-pixel match x − d: the pixel
            # fails only when both disagree (OpenCV StereoSGBM's disp12MaxDiff test)
            other = np.int64(right_best[xr])
            valid = other >= 0 and abs(other - best) <= lr_threshold
            occluded = other > best  # the right view sees something nearer there
            xr2 = xr - 1 if offset > 0 else xr + 1
            if not valid and offset != 0.0 and xr2 >= 0 and xr2 < width:
                other = np.int64(right_best[xr2])
                valid = other >= 0 and abs(other - best) <= lr_threshold
            if not valid and occluded:
                # occluded only when the epipolar line meets no right disparity that
                # points back to x (Hirschmüller 2008 §3.4): else a mismatch, which a
                # weak texture with a consistent match elsewhere on the line is
                for k in range(n_disp):
                    xk = x - (min_disparity + k)
                    if xk >= 0 and xk < width and right_best[xk] == k:
                        occluded = False
                        break
            if not valid:
                disparity[x] = np.nan
                confidence[x] = OCCLUDED if occluded else np.nan
                continue
        if not valid:
            disparity[x] = np.nan
            confidence[x] = np.nan
            continue
        disparity[x] = d_int + offset
        if second == 65535 or second == 0:
            confidence[x] = 1.0 if second == 65535 else 0.0
        else:
            confidence[x] = (np.float64(second) - np.float64(low)) / np.float64(second)


@njit(nogil=True, cache=True)
def _select_rows(total, min_disparity, mode, lr_threshold, left_valid, right_valid, row_start,
                 disparity, confidence):
    n_rows, width, _ = total.shape
    right_best = np.empty(width, dtype=np.int16)
    right_key = np.empty(width, dtype=np.uint32)
    for i in range(n_rows):
        select_row(total[i], row_start + i, min_disparity, mode, lr_threshold, left_valid,
                   right_valid, right_best, right_key, disparity[i], confidence[i])


def select_disparities(total: np.ndarray, *, min_disparity: int, left_valid: np.ndarray,
                       right_valid: np.ndarray, row_start: int = 0,
                       subpixel: str = "equiangular", lr_threshold: float | None = 1.0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Disparity and confidence from the aggregated cost of a strip of rows.

    Winner-takes-all d = argmin_d S(p, d); sub-pixel by a parabola or an equiangular
    (V-shaped) fit through S at d − 1, d, d + 1 (Shimizu & Okutomi 2001); the right
    image's disparity is d_R(x_r) = argmin_d S(x_r + d, d) from the same S, and the
    left pixel is kept only where |d_L − d_R(x − d_L)| ≤ ``lr_threshold``
    (Hirschmüller 2008, §3.1.4).

    Parameters
    ----------
    total : (h, W, D) uint16
        Aggregated cost of image rows ``row_start .. row_start + h``.
    min_disparity : int
        Disparity of index 0.
    left_valid, right_valid : (H, W) bool
        Valid input pixels of the whole images.
    row_start : int
        Image row of ``total[0]``.
    subpixel : {"equiangular", "parabola", "none"}
    lr_threshold : float or None
        Largest left–right difference in pixels; None skips the check.

    Returns
    -------
    disparity : (h, W) float32, pixels, NaN = invalid (NaN input, match outside the
        right image or on a NaN pixel, failed LR check)
    confidence : (h, W) float32 in [0, 1], (S₂ − S₁)/S₂ with S₁ the best aggregated
        cost and S₂ the best one at least two disparities away; :data:`OCCLUDED` where
        the LR check found an occlusion, NaN where otherwise invalid.
    """
    if subpixel not in SUBPIXEL_MODES:
        raise ValueError(f"unknown subpixel mode {subpixel!r}: should be one of "
                         + ", ".join(SUBPIXEL_MODES))
    n_rows, width, _ = total.shape
    disparity = np.empty((n_rows, width), dtype=np.float32)
    confidence = np.empty((n_rows, width), dtype=np.float32)
    threshold = -1 if lr_threshold is None else int(np.floor(lr_threshold))
    _select_rows(total, int(min_disparity), SUBPIXEL_MODES[subpixel], threshold, left_valid,
                 right_valid, int(row_start), disparity, confidence)
    return disparity, confidence


#: Fewest rows (or directions' pixels) worth a second thread in :func:`in_halves`.
MIN_SPLIT_ROWS = 64
def in_halves(work: Callable[[int, int], object], count: int,
              min_split: int | None = None) -> None:
    """Run ``work(start, stop)`` over ``0 … count`` in two halves on two threads.

    For the per-row (or per-direction) post-processing kernels, which release the GIL
    (numba ``nogil``): each half writes only its own rows, so the result is the one
    thread's, bit for bit.  One call ``work(0, count)`` when there is one core (or
    :func:`demtool.tiling.distributed.threads_limited` allows one thread) or fewer than
    ``min_split`` items (default :data:`MIN_SPLIT_ROWS`).  The second half runs on the
    calling thread's helper (:func:`demtool.tiling.rows.on_row_parts`), so concurrent
    callers (the tiles of a tiled run) never wait for one another's.  ``work`` should
    not call :func:`in_halves` itself.
    """
    min_split = MIN_SPLIT_ROWS if min_split is None else min_split
    on_row_parts(work, count, min_rows=max(1, min_split // 2), max_parts=2)


@njit(nogil=True, cache=True)
def _label_band(disparity, max_difference, label, sizes, stack, start, stop):
    """Number the 4-connected regions of rows ``start … stop − 1`` (not crossing the
    band's first or last row) in ``label``, from start·W + 1 on (so two bands never
    share a number); ``sizes[l]``: region l's pixel count; ``stack``: scratch of
    (stop − start)·W, from the caller (see :func:`_speckle_stage`)."""
    width = disparity.shape[1]
    current = start * width
    for y0 in range(start, stop):
        for x0 in range(width):
            if label[y0, x0] != 0 or not np.isfinite(disparity[y0, x0]):
                continue
            current += 1
            label[y0, x0] = current
            top = 0
            stack[0] = y0 * width + x0
            count = 0
            while top >= 0:
                index = stack[top]
                top -= 1
                count += 1
                y, x = divmod(index, width)
                value = disparity[y, x]
                for n in range(4):
                    yy = y + (1 if n == 0 else -1 if n == 1 else 0)
                    xx = x + (1 if n == 2 else -1 if n == 3 else 0)
                    if yy < start or yy >= stop or xx < 0 or xx >= width or label[yy, xx] != 0:
                        continue
                    other = disparity[yy, xx]
                    if np.isfinite(other) and abs(other - value) <= max_difference:
                        label[yy, xx] = current
                        top += 1
                        stack[top] = yy * width + xx
            sizes[current] = count


@njit(nogil=True, cache=True)
def _root(parent, node):
    while parent[node] != node:
        node = parent[node]
    return node


@njit(nogil=True, cache=True)
def _join_bands(disparity, max_difference, label, sizes, parent, joined, row):
    """Merge the regions that meet across rows ``row − 1`` and ``row`` (the edge of two
    bands of :func:`_label_band`): union–find over the labels on those rows
    (``joined[l]`` marks them, ``parent`` their tree); each root's ``sizes`` becomes
    its merged region's count."""
    width = disparity.shape[1] if row > 0 else 0
    for x in range(width):
        for y in (row - 1, row):
            node = label[y, x]
            if node > 0 and not joined[node]:
                joined[node] = True
                parent[node] = node
    for x in range(width):
        above, below = label[row - 1, x], label[row, x]
        if above == 0 or below == 0:
            continue
        if abs(disparity[row, x] - disparity[row - 1, x]) <= max_difference:
            a, b = _root(parent, above), _root(parent, below)
            if a != b:
                parent[max(a, b)] = min(a, b)
    for x in range(width):  # move each label's count to its root, once
        for y in (row - 1, row):
            node = label[y, x]
            if node > 0 and joined[node]:
                root = _root(parent, node)
                if root != node and sizes[node] >= 0:
                    sizes[root] += sizes[node]
                    sizes[node] = -1  # counted


@njit(nogil=True, cache=True)
def _drop_small(label, sizes, parent, joined, max_size, out, start, stop):
    """NaN in rows ``start … stop − 1`` of ``out`` where the pixel's region (merged
    across bands: :func:`_join_bands`) has fewer than ``max_size`` pixels."""
    width = label.shape[1]
    for y in range(start, stop):
        for x in range(width):
            node = label[y, x]
            if node == 0:
                continue
            if joined[node]:
                node = _root(parent, node)
            if sizes[node] < max_size:
                out[y, x] = np.nan


@njit(nogil=True, cache=True)
def _speckle_stage(stage, disparity, max_difference, max_size, label, sizes, parent, joined,
                   stack, out, start, stop):
    """One dispatcher (one cache load) for the steps of :func:`remove_speckles`: 0
    labels the band of rows ``start … stop − 1``, 1 joins the bands meeting at row
    ``start``, 2 drops the small regions from rows ``start … stop − 1``.  ``stack``
    (H·W) is the labelling's scratch, allocated by the caller: what numba allocates in
    the second thread stays in that thread's malloc arena (+16 MB of peak memory at
    2048²)."""
    width = disparity.shape[1]
    if stage == 0:
        _label_band(disparity, max_difference, label, sizes,
                    stack[start * width:stop * width], start, stop)
    elif stage == 1:
        _join_bands(disparity, max_difference, label, sizes, parent, joined, start)
    else:
        _drop_small(label, sizes, parent, joined, max_size, out, start, stop)


def remove_speckles(disparity: np.ndarray, *, max_size: int, max_difference: float
                    ) -> np.ndarray:
    """Invalidate small isolated regions of the disparity map (like ``cv2.filterSpeckles``).

    Regions are 4-connected sets of valid pixels whose neighbours differ by at most
    ``max_difference`` pixels; those with fewer than ``max_size`` pixels become NaN.
    Two halves of the rows are labelled in two threads and the regions that meet at
    their edge merged (union–find), which gives the regions of one labelling.

    Parameters
    ----------
    disparity : (H, W) float32, pixels, NaN = invalid
    max_size : int, pixels (0 = no filtering)
    max_difference : float, pixels

    Returns
    -------
    (H, W) float32, a filtered copy.
    """
    out = np.array(disparity, dtype=np.float32, copy=True)
    if max_size <= 0:
        return out
    source = np.ascontiguousarray(disparity, dtype=np.float32)
    height, width = source.shape
    label = np.zeros(source.shape, dtype=np.int32 if height * width < 2 ** 31 else np.int64)
    sizes = np.empty(height * width + 1, dtype=np.int64)
    parent = np.empty(height * width + 1, dtype=np.int64)
    joined = np.zeros(height * width + 1, dtype=np.bool_)
    starts: list[int] = []  # the bands labelled (two in two threads, else one)

    stack = np.empty(height * width, dtype=np.int64)

    def stage(step: int, start: int, stop: int) -> None:
        _speckle_stage(step, source, float(max_difference), int(max_size), label, sizes,
                       parent, joined, stack, out, start, stop)
        starts.append(start)

    in_halves(lambda start, stop: stage(0, start, stop), height)
    for start in sorted(starts):  # (row 0: nothing to join)
        stage(1, start, start)
    in_halves(lambda start, stop: stage(2, start, stop), height)
    return out


@njit(nogil=True, cache=True)
def _network_of_nine(p0, p1, p2, p3, p4, p5, p6, p7, p8):
    """Median of nine finite values by a 19-exchange sorting network (Paeth 1990,
    Graphics Gems)."""
    p1, p2 = min(p1, p2), max(p1, p2)
    p4, p5 = min(p4, p5), max(p4, p5)
    p7, p8 = min(p7, p8), max(p7, p8)
    p0, p1 = min(p0, p1), max(p0, p1)
    p3, p4 = min(p3, p4), max(p3, p4)
    p6, p7 = min(p6, p7), max(p6, p7)
    p1, p2 = min(p1, p2), max(p1, p2)
    p4, p5 = min(p4, p5), max(p4, p5)
    p7, p8 = min(p7, p8), max(p7, p8)
    p3 = max(p0, p3)
    p5 = min(p5, p8)
    p4, p7 = min(p4, p7), max(p4, p7)
    p6 = max(p3, p6)
    p4 = max(p1, p4)
    p2 = min(p2, p5)
    p4 = min(p4, p7)
    p4, p2 = min(p4, p2), max(p4, p2)
    p4 = max(p6, p4)
    return min(p4, p2)


@njit(nogil=True, cache=True)
def _nine_row(disparity, y, out):
    """``out[x]`` (x = 1 … W − 2): the median of the 3×3 window around (y, x) when all
    nine values are finite, else NaN — one branch-free loop over the row, so it
    vectorises (8 pixels per AVX2 instruction)."""
    width = disparity.shape[1]
    above, row, below = disparity[y - 1], disparity[y], disparity[y + 1]
    for x in range(1, width - 1):
        p0, p1, p2 = above[x - 1], above[x], above[x + 1]
        p3, p4, p5 = row[x - 1], row[x], row[x + 1]
        p6, p7, p8 = below[x - 1], below[x], below[x + 1]
        median = _network_of_nine(p0, p1, p2, p3, p4, p5, p6, p7, p8)
        total = p0 + p1 + p2 + p3 + p4 + p5 + p6 + p7 + p8
        out[x] = median if np.isfinite(total) else np.float32(np.nan)


@njit(nogil=True, cache=True)
def insert_sorted(values, count, value):
    """Insert ``value`` into ``values[:count]``, sorted ascending (insertion sort, for a
    few values); returns the new count."""
    j = count
    while j > 0 and values[j - 1] > value:
        values[j] = values[j - 1]
        j -= 1
    values[j] = value
    return count + 1


@njit(nogil=True, cache=True)
def sorted_median(values, count):
    """Median of ``values[:count]`` (sorted ascending, ``count`` ≥ 1): the middle one, or
    the mean of the middle two."""
    if count % 2 == 1:
        return values[count // 2]
    return 0.5 * (values[count // 2 - 1] + values[count // 2])


@njit(nogil=True, cache=True)
def _median(disparity, radius, out, start, stop):
    """Rows ``start … stop − 1`` of the NaN-aware median (see :func:`median_filter`)."""
    height, width = disparity.shape
    window = np.empty((2 * radius + 1) ** 2, dtype=np.float32)
    nine = np.full(width, np.nan, dtype=np.float32)
    for y in range(start, stop):
        fast = radius == 1 and 0 < y < height - 1
        if fast:
            _nine_row(disparity, y, nine)
        for x in range(width):
            if not np.isfinite(disparity[y, x]):
                out[y, x] = np.nan
                continue
            if fast and 0 < x < width - 1 and np.isfinite(nine[x]):  # all nine valid
                out[y, x] = nine[x]
                continue
            count = np.int64(0)  # not a literal 0: one compile of the helpers, not two
            for yy in range(max(y - radius, 0), min(y + radius + 1, height)):
                for xx in range(max(x - radius, 0), min(x + radius + 1, width)):
                    value = disparity[yy, xx]
                    if np.isfinite(value):  # sorted as the window fills (≤ 25 values)
                        count = insert_sorted(window, count, value)
            out[y, x] = sorted_median(window, count)


def median_filter(disparity: np.ndarray, size: int) -> np.ndarray:
    """NaN-aware median filter: each valid pixel becomes the median of the valid ones
    in its ``size × size`` window; invalid pixels stay NaN.

    Parameters
    ----------
    disparity : (H, W) float32, NaN = invalid
    size : int, odd (1 = no filtering)

    Returns
    -------
    (H, W) float32, a filtered copy.
    """
    if size <= 1:
        return np.array(disparity, dtype=np.float32, copy=True)
    if size % 2 == 0:
        raise ValueError(f"median size must be odd, got {size}")
    out = np.empty(disparity.shape, dtype=np.float32)
    source = np.ascontiguousarray(disparity, dtype=np.float32)
    in_halves(lambda start, stop: _median(source, size // 2, out, start, stop),
              source.shape[0])
    return out


@njit(cache=True, nogil=True)
def _unmatchable(disparity: np.ndarray, right_valid: np.ndarray, out: np.ndarray,
                 start: int, stop: int) -> None:
    """Copy rows ``start … stop − 1`` of ``disparity`` to ``out`` with NaN where x − d
    (rounded) misses valid right data."""
    width = disparity.shape[1]
    for y in range(start, stop):
        for x in range(width):
            d = disparity[y, x]
            out[y, x] = d
            if np.isfinite(d):
                matched = np.rint(x - d)
                if matched < 0 or matched >= width or not right_valid[y, int(matched)]:
                    out[y, x] = np.nan


def matchable(disparity: np.ndarray, right_valid: np.ndarray) -> np.ndarray:
    """NaN where the match x − d (rounded) is outside the right image or invalid there."""
    out = np.empty_like(disparity)
    valid = np.ascontiguousarray(right_valid)
    in_halves(lambda start, stop: _unmatchable(disparity, valid, out, start, stop),
              disparity.shape[0])  # rows on two threads: each writes its own
    return out
