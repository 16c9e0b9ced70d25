"""What was matched, and the fill of the rest: occlusions from the background, mismatches
from their confident neighbours (issue 26).

Every pixel of the output gets a class (:data:`MATCHED` … :data:`AT_BOUND`), written as
the ``--classes`` raster and counted in the log and sidecar, so that a user sees which
part of a disparity map passed the left–right check and which was filled.

The fill follows Hirschmüller (2008), §3.4 / Fig. 8, as CNES Pandora's ``"sgm"``
interpolation does (``pandora/validation/cpp/src/interpolated_disparity.cpp``):
the nearest matched disparity is searched in 8 directions; an occluded pixel takes the
background (the second lowest of them, so one outlier does not decide), a mismatched
pixel their median.  Pandora treats the mismatches that touch an occlusion as occluded;
here the occlusion is widened along the epipolar line instead (:func:`occluded_regions`):
in every invalid region that holds an occluded pixel, the first d(foreground) −
d(background) pixels of each row run after the visible background are occluded, which
is how wide an occlusion is; matched pixels inside that band past the invalid run are the
foreground fattened into the occlusion by the cost window and are filled as occluded
too (:func:`_unfatten`).  (Growing the whole region gave lower errors on the
Middlebury pairs but filled weakly textured foreground with background on the plank
pairs; a check that the right view hides the chosen background made it worse on both.)
"""

from __future__ import annotations

import numpy as np
from numba import njit

from demtool.sgm.disparity import in_halves, insert_sorted, sorted_median

INVALID = 0  # no disparity (NaN in the output)
MATCHED = 1  # passed the left–right check and the filters
FILLED_OCCLUSION = 2  # occluded in the right view, filled from the background
FILLED_MISMATCH = 3  # failed the check or a filter, filled from its neighbours
AT_BOUND = 4  # matched, but at the lowest or highest disparity searched

CLASS_NAMES = {INVALID: "invalid", MATCHED: "matched", FILLED_OCCLUSION: "filled_occlusion",
               FILLED_MISMATCH: "filled_mismatch", AT_BOUND: "at_range_bound"}


_DIRECTIONS = np.array([[0, 1], [0, -1], [1, 0], [-1, 0], [1, 1], [1, -1], [-1, 1], [-1, -1]],
                       dtype=np.int64)


@njit(nogil=True, cache=True)
def _nearest_along(disparity, usable, index, dy, dx, found, k):
    """found[k, index[y, x]] = the first valid disparity at (y, x) + t (dy, dx), t ≥ 1.

    One pass from the far end, carrying per column the nearest valid value at or
    beyond each pixel (NaN past a pixel outside ``usable``): O(H W) per direction.
    """
    height, width = disparity.shape
    carry = np.full(width, np.nan, dtype=np.float32)
    new = np.full(width, np.nan, dtype=np.float32)
    first, last, step = (height - 1, -1, -1) if dy > 0 else (0, height, 1)
    for y in range(first, last, step):
        if dy == 0:  # along the row, from its far end
            ahead = np.float32(np.nan)
            x0, x1, sx = (width - 1, -1, -1) if dx > 0 else (0, width, 1)
            for x in range(x0, x1, sx):
                if index[y, x] >= 0:
                    found[k, index[y, x]] = ahead
                value = disparity[y, x]
                if not usable[y, x]:
                    ahead = np.float32(np.nan)
                elif np.isfinite(value):
                    ahead = value
            continue
        for x in range(width):
            xx = x + dx
            ahead = carry[xx] if 0 <= xx < width else np.float32(np.nan)
            if index[y, x] >= 0:
                found[k, index[y, x]] = ahead
            value = disparity[y, x]
            if not usable[y, x]:
                new[x] = np.nan
            elif np.isfinite(value):
                new[x] = value
            else:
                new[x] = ahead
        for x in range(width):
            carry[x] = new[x]


@njit(nogil=True, cache=True)
def _fill_index(disparity, usable, index):
    """``index[y, x]``: the number of the invalid usable pixel (row-major), else −1;
    returns their count."""
    height, width = disparity.shape
    count = 0
    for y in range(height):
        for x in range(width):
            if usable[y, x] and not np.isfinite(disparity[y, x]):
                index[y, x] = count
                count += 1
            else:
                index[y, x] = -1
    return count


@njit(nogil=True, cache=True)
def _nearest_directions(disparity, usable, index, directions, found, start, stop):
    """:func:`_nearest_along` for directions ``start … stop − 1``."""
    for k in range(start, stop):
        _nearest_along(disparity, usable, index, directions[k, 0], directions[k, 1], found, k)


@njit(nogil=True, cache=True)
def _fill_rows(occluded, index, found, out, start, stop):
    """Rows ``start … stop − 1`` of the fill from the nearest values ``found``."""
    width = index.shape[1]
    n_dir = found.shape[0]
    values = np.empty(n_dir, dtype=np.float32)
    for y in range(start, stop):
        for x in range(width):
            i = index[y, x]
            if i < 0:
                continue
            n = np.int64(0)  # not a literal 0: one compile of insert_sorted, not two
            for k in range(n_dir):
                value = found[k, i]
                if np.isfinite(value):
                    n = insert_sorted(values, n, value)
            if n == 0:
                continue
            if occluded[y, x]:  # the background: the second lowest (one outlier allowed)
                out[y, x] = values[1] if n > 2 else values[0]
            else:
                out[y, x] = sorted_median(values, n)


@njit(nogil=True, cache=True)
def _fill_stage(stage, disparity, occluded, usable, directions, index, found, out, start,
                stop):
    """One dispatcher for the fill's three steps (each numba dispatcher a process calls
    costs ~5 ms to load from the cache): 0 numbers the pixels to fill (returns their
    count), 1 searches directions ``start … stop − 1``, 2 fills rows ``start … stop − 1``."""
    if stage == 0:
        return _fill_index(disparity, usable, index)
    if stage == 1:
        _nearest_directions(disparity, usable, index, directions, found, start, stop)
    else:
        _fill_rows(occluded, index, found, out, start, stop)
    return 0


def fill_nearest(disparity: np.ndarray, occluded: np.ndarray, usable: np.ndarray,
                 out: np.ndarray) -> None:
    """The fill of :func:`fill_invalid` into ``out`` (a copy of ``disparity``); all
    arrays C-contiguous.  The 8 directions' searches, then the rows, in two threads
    (:func:`in_halves`)."""
    index = np.empty(disparity.shape, dtype=np.int64)
    n_dir = _DIRECTIONS.shape[0]

    def stage(step, found, start=0, stop=0):
        return _fill_stage(step, disparity, occluded, usable, _DIRECTIONS, index, found, out,
                           start, stop)

    count = stage(0, np.empty((n_dir, 0), dtype=np.float32))
    found = np.empty((n_dir, count), dtype=np.float32)
    in_halves(lambda start, stop: stage(1, found, start, stop), n_dir,
              min_split=2 if count >= 4096 else n_dir + 1)
    in_halves(lambda start, stop: stage(2, found, start, stop), disparity.shape[0])


def fill_invalid(disparity: np.ndarray, occluded: np.ndarray, usable: np.ndarray
                 ) -> np.ndarray:
    """Fill invalid pixels from the nearest valid disparities in 8 directions.

    Hirschmüller (2008), §3.1.5 (Fig. 8): an occluded pixel takes the background — the
    second lowest of the eight disparities, so one outlier does not decide — and any
    other invalid pixel (a mismatch) their median.  Searches stop at pixels outside
    ``usable``, which are never filled.

    Parameters
    ----------
    disparity : (H, W) float32, pixels, NaN = invalid
    occluded : (H, W) bool
        Invalid pixels that the left–right check found occluded.
    usable : (H, W) bool
        Pixels that may be filled and that searches may cross (the valid left image).

    Returns
    -------
    (H, W) float32, a filled copy (pixels no search reached stay NaN).
    """
    out = np.array(disparity, dtype=np.float32, copy=True)
    fill_nearest(np.ascontiguousarray(disparity, dtype=np.float32),
                 np.ascontiguousarray(occluded, dtype=np.bool_),
                 np.ascontiguousarray(usable, dtype=np.bool_), out)
    return out


@njit(nogil=True, cache=True)
def _next_invalid_run(disparity, usable, flags, y, x):
    """The first run of usable pixels without a disparity at or after column ``x`` of
    row ``y``: (start, stop (exclusive), whether ``flags`` is set on any of its pixels);
    start = stop = W when there is none."""
    width = disparity.shape[1]
    while x < width and (not usable[y, x] or np.isfinite(disparity[y, x])):
        x += 1
    start = x
    flagged = False
    while x < width and usable[y, x] and not np.isfinite(disparity[y, x]):
        flagged = flagged or flags[y, x]
        x += 1
    return start, x, flagged


@njit(nogil=True, cache=True)
def _epipolar_occlusions(disparity, occluded, touched, usable, out, start, stop):
    """Per row (``start … stop − 1``), each run of invalid pixels that holds an occluded
    one: its first ``jump`` pixels are occluded, jump = d(right end) − d(left end) of
    the run."""
    width = disparity.shape[1]
    for y in range(start, stop):
        x = np.int64(0)  # not a literal 0: one compile of _next_invalid_run, not two
        while x < width:
            start, x, any_occluded = _next_invalid_run(disparity, usable, touched, y, x)
            stop = x  # exclusive
            if not any_occluded:
                continue
            left = disparity[y, start - 1] if start > 0 else np.float32(np.nan)
            right = disparity[y, stop] if stop < width else np.float32(np.nan)
            for xx in range(start, stop):
                out[y, xx] = occluded[y, xx]
            if np.isfinite(left) and np.isfinite(right) and right > left:
                jump = int(np.ceil(right - left))
                for xx in range(start, min(stop, start + jump)):
                    out[y, xx] = True
            elif not np.isfinite(left):  # the run starts at the image's edge
                for xx in range(start, stop):
                    out[y, xx] = True


@njit(nogil=True, cache=True)
def _unfatten(disparity, occluded, usable, out, marked, start, stop):
    """Per row (``start … stop − 1``): after the last visible background pixel
    (disparity d_b) an occlusion is d_f − d_b pixels wide, d_f the foreground's;
    matched pixels inside that band, past an invalid run that holds an occluded pixel,
    are the foreground fattened into the occlusion: NaN in ``out``, True in
    ``marked``."""
    width = disparity.shape[1]
    for y in range(start, stop):
        x = np.int64(0)  # not a literal 0: one compile of _next_invalid_run, not two
        while x < width:
            start, x, any_occluded = _next_invalid_run(disparity, usable, occluded, y, x)
            stop = x  # exclusive
            if not any_occluded or start == 0 or stop >= width:
                continue
            left, right = disparity[y, start - 1], disparity[y, stop]
            if not (np.isfinite(left) and np.isfinite(right)) or right <= left + 1.0:
                continue
            end = min(width, start + int(np.floor(right - left)))
            for xx in range(stop, end):
                if not usable[y, xx] or not np.isfinite(disparity[y, xx]):
                    break
                if disparity[y, xx] <= left + 1.0:  # background again: no fattening
                    break
                out[y, xx] = np.nan
                marked[y, xx] = True


def occluded_regions(disparity: np.ndarray, invalid: np.ndarray, occluded: np.ndarray
                     ) -> np.ndarray:
    """(H, W) bool: the invalid pixels to fill as occlusions.

    The pixels the left–right check found occluded, and in each 8-connected invalid
    region that holds one, the first ``d(right end) − d(left end)`` pixels of each of
    its row runs: along the epipolar line an occlusion is as wide as the disparity
    jump, and it starts where the visible background ends; the rest of a long run
    (weak texture on the foreground that failed the check) stays a mismatch.
    """
    invalid = np.ascontiguousarray(invalid, dtype=np.bool_)
    seeds = np.ascontiguousarray(occluded & invalid)
    touched = np.zeros(invalid.shape, dtype=np.bool_)
    _grow_regions(invalid, seeds, touched)
    out = np.zeros(invalid.shape, dtype=np.bool_)
    usable = invalid | np.isfinite(disparity)
    in_halves(lambda start, stop: _epipolar_occlusions(disparity, seeds, touched, usable, out,
                                                       start, stop), invalid.shape[0])
    return out


@njit(cache=True, nogil=True)
def _grow_regions(inside, seeds, out):
    """``out``: the pixels of ``inside`` 8-connected (within ``inside``) to a pixel of
    ``seeds`` — the regions ``scipy.ndimage.label`` would number that hold a seed, without
    the labels (and without scipy's import, about 0.3 s of CPU at each start)."""
    height, width = inside.shape
    stack = np.empty(height * width, dtype=np.int64)
    top = 0
    for y in range(height):
        for x in range(width):
            if seeds[y, x] and inside[y, x] and not out[y, x]:
                out[y, x] = True
                stack[top] = y * width + x
                top += 1
    while top > 0:
        top -= 1
        y, x = divmod(stack[top], width)
        for dy in range(-1, 2):
            yy = y + dy
            if yy < 0 or yy >= height:
                continue
            for dx in range(-1, 2):
                xx = x + dx
                if 0 <= xx < width and inside[yy, xx] and not out[yy, xx]:
                    out[yy, xx] = True
                    stack[top] = yy * width + xx
                    top += 1


def fill_classified(disparity: np.ndarray, occluded: np.ndarray, usable: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Fill the invalid pixels and say which were filled how.

    Parameters
    ----------
    disparity : (H, W) float32, pixels, NaN = invalid
        The matched disparities (after the left–right check and the filters).
    occluded : (H, W) bool
        Invalid pixels that the left–right check found occluded (the right view
        shows something nearer at their match).
    usable : (H, W) bool
        Pixels that may be filled and that searches may cross (the valid left image).

    Returns
    -------
    disparity : (H, W) float32, the filled copy (pixels no search reached stay NaN)
    classes : (H, W) uint8, :data:`MATCHED` (the fattened pixels :func:`_unfatten`
        finds are filled occlusions), :data:`FILLED_OCCLUSION`,
        :data:`FILLED_MISMATCH` or :data:`INVALID` (range bounds are not marked here:
        :func:`classify`).
    """
    disparity = np.ascontiguousarray(disparity, dtype=np.float32)
    thin = disparity.copy()  # the foreground fattened into occlusions: refilled
    marked = np.zeros(disparity.shape, dtype=np.bool_)
    seeds = np.ascontiguousarray(occluded & ~np.isfinite(disparity))
    usable = np.ascontiguousarray(usable, dtype=np.bool_)
    in_halves(lambda start, stop: _unfatten(disparity, seeds, usable, thin, marked, start, stop),
              disparity.shape[0])
    disparity = thin
    occluded = occluded | marked
    matched = np.isfinite(disparity)
    invalid = usable & ~matched
    occluded_all = occluded_regions(disparity, invalid, occluded)
    out = disparity.copy()
    fill_nearest(disparity, np.ascontiguousarray(occluded_all), usable, out)
    classes = np.full(disparity.shape, INVALID, dtype=np.uint8)
    filled = invalid & np.isfinite(out)
    classes[matched] = MATCHED
    classes[filled & occluded_all] = FILLED_OCCLUSION
    classes[filled & ~occluded_all] = FILLED_MISMATCH
    return out, classes


def classify(disparity: np.ndarray, classes: np.ndarray | None, min_disparity: int,
             num_disparities: int) -> np.ndarray:
    """The final class raster: matched pixels at a range bound become :data:`AT_BOUND`,
    pixels NaN in the output :data:`INVALID`.

    A matched disparity within half a pixel of ``min_disparity`` or of the largest
    disparity searched is at a bound: the true one may lie beyond it.
    """
    finite = np.isfinite(disparity)
    out = (np.where(finite, MATCHED, INVALID).astype(np.uint8) if classes is None
           else np.where(finite, classes, INVALID).astype(np.uint8))
    high = min_disparity + num_disparities - 1
    with np.errstate(invalid="ignore"):
        bound = finite & ((disparity < min_disparity + 0.5) | (disparity > high - 0.5))
    out[bound & (out == MATCHED)] = AT_BOUND
    return out


def class_fractions(classes: np.ndarray, valid_input: np.ndarray) -> dict[str, float]:
    """Fraction of the valid input pixels in each class (keys :data:`CLASS_NAMES`)."""
    total = max(int(valid_input.sum()), 1)
    return {name: round(float(np.count_nonzero((classes == value) & valid_input)) / total, 4)
            for value, name in CLASS_NAMES.items()}
