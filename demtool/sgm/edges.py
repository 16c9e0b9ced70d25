"""Foreground fattened across depth edges, moved back onto the image's edges (issue 26).

A matching cost computed over a patch (census 5×5, the cost window) lets a textured
foreground claim up to the patch's half-width of the background beside it.  Those
pixels pass the left–right check, because the right image's disparity is fattened
alike (Hirschmüller 2008 §3.4; Scharstein & Szeliski 2002 §5.4 call it the
"foreground fattening" of window costs); in the benchmark's occlusions they were most of
the error.  The true depth edge lies on the foreground's side of the jump, within that
half-width, where the left image has its intensity edge.  :func:`snap_edges` moves each
jump there: along every row and column, the pixels between the jump and the strongest
intensity step of the band are given to the background — an edge only where the step
is at least ``min_step`` (the adaptive P2's κ: steps within a few noise σ are no edges,
so weakly textured, noisy images are left alone) and stronger than the step at the jump.
Where the background side is an occlusion the left–right check found (the left image's
occlusions lie left of a foreground), the pixels passed join the occlusion and are
filled from the background (:mod:`demtool.sgm.fill`).  Mei et al. (2011), "On building
an accurate stereo matching system on graphics hardware", §2.4 adjust such pixels by
their cost; the image's own edge needs no cost volume.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from demtool.sgm.disparity import in_halves

#: Smallest disparity step (px) between neighbours treated as a depth discontinuity.
EDGE_JUMP = 2.0


@njit(nogil=True, cache=True)
def _edge_offset(disparity, image, step, y, p, sign, foreground, radius, min_step):
    """How many foreground pixels past the background pixel ``p`` (towards ``sign``)
    the edge really lies: the k ≤ ``radius`` whose step (between p + sign·k and
    p + sign·(k + 1)) is the largest, at least ``min_step`` and above the step at the
    jump (k = 0), cut short at the first pixel whose intensity is nearer the
    foreground's (beyond that edge) than the background's (at p − sign).  ``step[y, u]`` is
    the intensity step between u and u + 1."""
    length = disparity.shape[1]
    best = step[y, p] if sign > 0 else step[y, p - 1]
    best_k = 0
    for k in range(1, radius + 1):
        xx = p + sign * k
        if xx < 1 or xx >= length - 1 or not np.isfinite(disparity[y, xx]):
            break
        if abs(disparity[y, xx] - foreground) > 1.0:
            break
        s = step[y, xx] if sign > 0 else step[y, xx - 1]
        if s > best and s >= min_step:
            best = s
            best_k = k
    if best_k == 0:
        return 0
    # the pixels given away must look like the background, not like the foreground
    outer = p - sign  # one pixel into the background: the jump's own pixel may be mixed
    background = image[y, outer if 0 <= outer < length else p]
    foreground = image[y, p + sign * (best_k + 1)]
    for k in range(1, best_k + 1):
        value = image[y, p + sign * k]
        if abs(value - background) >= abs(value - foreground):
            return k - 1
    return best_k


# One compiled version for both passes: the row pass gives C-ordered arrays, the column pass
# their transposed views (F-ordered); arrays of any layout ("A", ``[:, :]``) take both, where
# compiling on first use made one version per layout (1.9 CPU s each in a fresh clone).
_LINES_SIGNATURE = ("void(float32[:, :], float32[:, :], float32[:, :], boolean[:, :], int64, "
                    "float64, float64, float32[:, :], boolean[:, :], int64, int64)")


@njit(_LINES_SIGNATURE, nogil=True, cache=True)
def _snap_lines(disparity, image, step, occluded, radius, jump, min_step, out, moved, start,
                stop):
    """Lines ``start … stop − 1`` along the last axis (see :func:`snap_edges`);
    ``occluded`` marks the invalid pixels the check found occluded.  The column pass
    gives transposed views (no copies)."""
    length = disparity.shape[1]
    # the directions as int64, not literals: one compile of _edge_offset, not two
    rightwards, leftwards = np.int64(1), np.int64(-1)
    for y in range(start, stop):
        for x in range(length - 1):
            a = disparity[y, x]
            b = disparity[y, x + 1]
            if not np.isfinite(b):
                continue
            if not np.isfinite(a):
                if occluded[y, x]:  # an occlusion, then the foreground: NaN, occluded
                    k = _edge_offset(disparity, image, step, y, x, rightwards, b, radius,
                                     min_step)
                    for i in range(1, k + 1):
                        out[y, x + i] = np.nan
                        moved[y, x + i] = True
            elif b - a > jump:  # the foreground on the right
                k = _edge_offset(disparity, image, step, y, x, rightwards, b, radius,
                                 min_step)
                for i in range(1, k + 1):
                    out[y, x + i] = a
                    moved[y, x + i] = True
            elif a - b > jump:  # the foreground on the left
                k = _edge_offset(disparity, image, step, y, x + 1, leftwards, a, radius,
                                 min_step)
                for i in range(1, k + 1):
                    out[y, x + 1 - i] = b
                    moved[y, x + 1 - i] = True


@njit(nogil=True, cache=True)
def _smooth_rows(image, smooth, steps, start, stop, along):
    """Rows ``start … stop − 1`` of :func:`_smooth_and_steps` (float32 arithmetic in
    numpy's order: the same bits as ``0.25 * a + 0.5 * b + 0.25 * c`` of float32 arrays)."""
    height, width = image.shape
    quarter, half = np.float32(0.25), np.float32(0.5)
    for y in range(start, stop):
        above, below = max(y - 1, 0), min(y + 1, height - 1)
        for x in range(width):
            if along == 1:  # [1 2 1] across the rows
                first, last = image[above, x], image[below, x]
            else:  # across the columns
                first, last = image[y, max(x - 1, 0)], image[y, min(x + 1, width - 1)]
            smooth[y, x] = (quarter * np.float32(first) + half * np.float32(image[y, x])
                            + quarter * np.float32(last))
        if along == 1:
            for x in range(width - 1):
                steps[y, x] = abs(smooth[y, x + 1] - smooth[y, x])
            steps[y, width - 1] = 0.0
    if along == 0:  # steps down the columns: rows start … stop − 1 need row stop smoothed
        for y in range(start, stop):
            if y == height - 1:
                for x in range(width):
                    steps[y, x] = 0.0
                continue
            for x in range(width):
                if y + 1 < stop:
                    below_value = smooth[y + 1, x]
                else:  # the next half's first row, smoothed here too
                    left, right = image[y + 1, max(x - 1, 0)], image[y + 1, min(x + 1, width - 1)]
                    below_value = (quarter * np.float32(left)
                                   + half * np.float32(image[y + 1, x])
                                   + quarter * np.float32(right))
                steps[y, x] = abs(below_value - smooth[y, x])


def _smooth_and_steps(image: np.ndarray, along: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """For lines along axis ``along`` (1: rows, 0: columns): the image smoothed [1 2 1]
    across the lines (edges replicated), and |I(u + 1) − I(u)| of it along them
    (float32, 0 at each line's end)."""
    image = np.ascontiguousarray(image)
    smooth = np.empty(image.shape, dtype=np.float32)
    steps = np.empty(image.shape, dtype=np.float32)
    in_halves(lambda start, stop: _smooth_rows(image, smooth, steps, start, stop, along),
              image.shape[0])
    return smooth, steps


def _snap(disparity, image, occluded, radius, jump, min_step, along=1):
    """One pass of :func:`snap_edges` along the rows (``along`` = 1) or the columns (0:
    the kernel gets transposed views, so nothing is copied into the other layout)."""
    out = disparity.copy()
    moved = np.zeros(disparity.shape, dtype=np.bool_)
    smooth, steps = _smooth_and_steps(image, along)
    arrays = (disparity, smooth, steps, occluded, out, moved)
    if along == 0:
        arrays = tuple(array.T for array in arrays)
    source, smooth, steps, occluded, target, marked = arrays
    in_halves(lambda start, stop: _snap_lines(source, smooth, steps, occluded, int(radius),
                                              float(jump), float(min_step), target, marked,
                                              start, stop),
              source.shape[0])
    return out, moved


def snap_edges(disparity: np.ndarray, image: np.ndarray, radius: int,
               occluded: np.ndarray | None = None, *, min_step: float = 0.0,
               jump: float = EDGE_JUMP) -> tuple[np.ndarray, np.ndarray]:
    """Move the depth edges of a disparity map onto the intensity edges of its image.

    Parameters
    ----------
    disparity : (H, W) float32, pixels, NaN = invalid
        Left disparity after the left–right check.
    image : (H, W) float or uint8
        The left image (invalid pixels filled), e.g. the 0 … 255 guide.
    radius : int
        Largest fattening, px: the half-width of the patch the cost compares.
    occluded : (H, W) bool, optional
        Invalid pixels the left–right check found occluded.
    min_step : float
        Smallest intensity step (image units) that is an edge.
    jump : float
        Smallest disparity step between neighbours that is a depth edge, px.

    Returns
    -------
    disparity : (H, W) float32
        Rows first, then columns: fattened pixels beside a matched background take its
        disparity; those beside an occlusion (along a row) are NaN.
    moved : (H, W) bool
        The pixels changed.
    """
    disparity = np.ascontiguousarray(disparity, dtype=np.float32)
    if radius < 1:
        return disparity, np.zeros(disparity.shape, dtype=np.bool_)
    occluded = (np.zeros(disparity.shape, dtype=np.bool_) if occluded is None
                else np.ascontiguousarray(occluded, dtype=np.bool_))
    rows, moved_rows = _snap(disparity, image, occluded, radius, jump, min_step)
    columns, moved_columns = _snap(rows, image, np.zeros(rows.shape, dtype=np.bool_), radius,
                                   jump, min_step, along=0)
    moved_columns |= moved_rows
    return columns, moved_columns
