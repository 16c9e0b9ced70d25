"""Semi-global cost aggregation along 8 or 16 image paths (Hirschmüller 2008, §3.1.3).

For each path direction r the cost is aggregated recursively (eq. 13):

    L_r(p, d) = C(p, d) + min(L_r(p − r, d),
                              L_r(p − r, d − 1) + P1,
                              L_r(p − r, d + 1) + P1,
                              min_i L_r(p − r, i) + P2) − min_k L_r(p − r, k)

and the aggregated cost is S(p, d) = Σ_r L_r(p, d) (eq. 14).  P2 can be adapted to
the intensity step along the path, P2 = max(P1, P2' · κ / max(|I_p − I_{p−r}|, κ)),
so depth discontinuities at intensity edges are cheaper (Hirschmüller 2008, §3.1.3).

The work is two row sweeps: down (top to bottom) for the directions with a downward
component plus left-to-right, and up for the opposite ones plus right-to-left.  A
sweep computes the window-summed matching cost C row by row as it goes
(:func:`demtool.sgm.cost.advance_window`), so no cost volume is ever held; besides
the aggregated-cost volume S (uint16) it keeps only the last two rows (three for the
16-path knight moves) of path costs per direction.  The sweeps can run at once in two
threads: each first covers its half of the rows and stores its partial sum in S, then,
after both are done, continues into the other half, where it adds its own sum to the
stored one and selects the disparity of the finished row (:func:`sweep_rows`).  No
row is computed twice and no strip overlap is needed.

numba's on-disk cache would not notice edits to the kernels :func:`sweep_rows` inlines
from :mod:`demtool.sgm.cost` and :mod:`demtool.sgm.disparity`; it closes over a digest
of those files (:func:`callee_sources_digest`) so that their edits recompile it.

Four path directions are updated in one loop over the disparities (int16, branch-free,
16 lanes per AVX2 vector), so their sum is formed in registers.  Path costs are int16
(L ≤ C_max + P2) and sums uint16 (≤ n_paths · (C_max + P2)); callers check the bound.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from demtool.sgm.cost import advance_window, volume_source
from demtool.sgm.disparity import select_row
from demtool.sgm.simd import LANES, paths_row, paths_row_add

# int16 sentinel for the path cost beyond the disparity range; SENTINEL + P1 must fit int16
SENTINEL = 16383
MAX_P1 = 16383
# zero columns on each side of the path buffers (the 16-path knight moves reach two columns)
PAD = 2
MODE_STORE, MODE_ADD, MODE_FINISH, MODE_DISCARD = 0, 1, 2, 3

# Path directions (dy, dx), dy ≥ 0, in groups of four updated together; the down sweep
# runs them as given, the up sweep their opposites.
_GROUP_8 = ((0, 1), (1, -1), (1, 0), (1, 1))
_GROUP_16 = ((1, -2), (1, 2), (2, -1), (2, 1))


def path_groups(paths: int) -> np.ndarray:
    """The path directions of one sweep, (groups, 4, 2) int64 of (dy, dx) with dy ≥ 0.

    The full set of an 8- or 16-path SGM is these and their opposites.
    """
    if paths == 8:
        return np.array([_GROUP_8], dtype=np.int64)
    if paths == 16:
        return np.array([_GROUP_8, _GROUP_16], dtype=np.int64)
    raise ValueError(f"paths must be 8 or 16, got {paths}")


def _define_four_paths(callee_digest: str):
    @njit(nogil=True, cache=True, fastmath=True)
    def _four_paths(buf, mins, j0, slot, col, s0, c0, e0, s1, c1, e1, s2, c2, e2, s3, c3, e3,
                    cost, x, p1, out, accumulate):
        """Eq. 13 for four path directions j0 .. j0 + 3 at pixel x, all disparities.

        ``buf[s, j, c, 1:D+1]`` holds L_r of direction j in ring slot s at buffer column c,
        with sentinels at both ends of the disparity axis; path t reads L_r(p − r) at
        slot ``s<t>``, column ``c<t>`` (its minimum over d at ``mins[s<t>, j, c<t>]``) and
        uses P2 = ``e<t>``.  The new L_r go to column ``col`` of ``slot``, their minima to
        ``mins``; their sum is written to (or, with ``accumulate``, added to) ``out[x]``.
        Plain numba loops, for D < 16 (:func:`demtool.sgm.simd.paths_row` does D ≥ 16).
        """
        if callee_digest == "":  # never: it puts the digest into numba's cache key
            return
        n_disp = cost.shape[1]
        j1, j2, j3 = j0 + 1, j0 + 2, j0 + 3
        m0, m1 = mins[s0, j0, c0], mins[s1, j1, c1]
        m2, m3 = mins[s2, j2, c2], mins[s3, j3, c3]
        low0 = low1 = low2 = low3 = np.int16(32767)
        a0, a1 = np.int16(m0 + e0), np.int16(m1 + e1)
        a2, a3 = np.int16(m2 + e2), np.int16(m3 + e3)
        # branch-free accumulation (a conditional load in the loop would stop vectorisation)
        keep = np.uint16(0xFFFF) if accumulate else np.uint16(0)
        for k in range(1, n_disp + 1):
            c = np.int16(cost[x, k - 1])
            v0 = np.int16(c + np.int16(min(min(buf[s0, j0, c0, k], np.int16(
                min(buf[s0, j0, c0, k - 1], buf[s0, j0, c0, k + 1]) + p1)), a0) - m0))
            v1 = np.int16(c + np.int16(min(min(buf[s1, j1, c1, k], np.int16(
                min(buf[s1, j1, c1, k - 1], buf[s1, j1, c1, k + 1]) + p1)), a1) - m1))
            v2 = np.int16(c + np.int16(min(min(buf[s2, j2, c2, k], np.int16(
                min(buf[s2, j2, c2, k - 1], buf[s2, j2, c2, k + 1]) + p1)), a2) - m2))
            v3 = np.int16(c + np.int16(min(min(buf[s3, j3, c3, k], np.int16(
                min(buf[s3, j3, c3, k - 1], buf[s3, j3, c3, k + 1]) + p1)), a3) - m3))
            buf[slot, j0, col, k] = v0
            buf[slot, j1, col, k] = v1
            buf[slot, j2, col, k] = v2
            buf[slot, j3, col, k] = v3
            total = np.uint16(np.uint16(v0) + np.uint16(v1) + np.uint16(v2) + np.uint16(v3))
            out[x, k - 1] = np.uint16(np.uint16(out[x, k - 1] & keep) + total)
            low0 = min(low0, v0)
            low1 = min(low1, v1)
            low2 = min(low2, v2)
            low3 = min(low3, v3)
        mins[slot, j0, col] = low0
        mins[slot, j1, col] = low1
        mins[slot, j2, col] = low2
        mins[slot, j3, col] = low3

    return _four_paths


def adapted_p2_table(p1: int, p2: int, kappa: int) -> np.ndarray:
    """P2 for every grey-level step 0..255 along a path (Hirschmüller 2008, §3.1.3).

    ``max(P1, P2·κ/|ΔI|)`` where |ΔI| > κ, else P2 (κ ≤ 0: P2 everywhere); a table, so
    the sweeps do no division per pixel and path.

    Returns
    -------
    (256,) int64
    """
    steps = np.arange(256)
    if kappa <= 0:
        return np.full(256, p2, dtype=np.int64)
    lowered = np.maximum(p1, (p2 * kappa) // np.maximum(steps, 1))
    return np.where(steps <= kappa, p2, lowered).astype(np.int64)


def callee_sources_digest() -> str:
    """SHA-256 of :mod:`demtool.sgm.cost`, :mod:`demtool.sgm.disparity` and
    :mod:`demtool.sgm.simd`, whose kernels :func:`sweep_rows`, ``_four_paths`` and
    ``_paths_rows`` inline.

    numba's on-disk cache knows only the compiled function's own file and bytecode (and
    its closure variables), so :func:`sweep_rows` closes over this digest: an edit of
    those modules then recompiles it instead of running stale machine code.
    """
    digest = hashlib.sha256()
    for name in ("cost.py", "disparity.py", "simd.py"):
        digest.update((Path(__file__).with_name(name)).read_bytes())
    return digest.hexdigest()


_four_paths = _define_four_paths(callee_sources_digest())


def _define_paths_rows(callee_digest: str):
    @njit(nogil=True, cache=True)
    def _paths_rows(buf, mins, cost, out, penalty, n_groups, slot, previous_slot,
                    column_step, sign, p1):
        """Eq. 13 along one image row for every group of four directions (D ≥ 16).

        The offsets of the row's first pixel (in sweep order) in the path buffers
        ``buf[slot, j, column, 1:D+1]`` and ``mins``, in ``cost``/``out`` and in
        ``penalty`` for :func:`demtool.sgm.simd.paths_row`, which runs the row; the
        arguments as in :func:`sweep_rows`.
        """
        if callee_digest == "":  # never: it puts the digest into numba's cache key
            return
        n_dirs, columns, padded = buf.shape[1], buf.shape[2], buf.shape[3]
        width, n_disp = cost.shape
        x0 = 0 if sign > 0 else width - 1
        col = x0 + PAD
        steps = (sign * padded, np.int64(sign), sign * n_disp, np.int64(sign),
                 columns * padded, np.int64(columns))
        for g in range(n_groups):
            j = 4 * g
            w0 = (previous_slot[j] * n_dirs + j) * columns + col + column_step[j]
            w1 = (previous_slot[j + 1] * n_dirs + j + 1) * columns + col + column_step[j + 1]
            w2 = (previous_slot[j + 2] * n_dirs + j + 2) * columns + col + column_step[j + 2]
            w3 = (previous_slot[j + 3] * n_dirs + j + 3) * columns + col + column_step[j + 3]
            prev = (w0 * padded + 1, w1 * padded + 1, w2 * padded + 1, w3 * padded + 1)
            pens = (j * width + x0, (j + 1) * width + x0, (j + 2) * width + x0,
                    (j + 3) * width + x0)
            here = (slot * n_dirs + j) * columns + col
            cur = (here * padded + 1, here)
            # group 0's first direction is the horizontal (0, 1) (path_groups): its
            # predecessor is the previous pixel, whose minimum paths_row keeps in a register
            if g == 0:
                paths_row(buf, mins, cost, out, penalty, cur, prev, (w0, w1, w2, w3), pens,
                          steps, x0 * n_disp, width, np.int64(p1))
            else:
                paths_row_add(buf, mins, cost, out, penalty, cur, prev, (w0, w1, w2, w3),
                              pens, steps, x0 * n_disp, width, np.int64(p1))

    return _paths_rows


_paths_rows = _define_paths_rows(callee_sources_digest())


def _define_sweep_rows(callee_digest: str):
    @njit(nogil=True, cache=True, fastmath=True)
    def sweep_rows(source, radius, guide, groups, p1, p2_table, sign, first, stop, lo, hi,
                   buf, mins, ring, running, pixel, window_state, mode, total, total_base,
                   scratch, subpixel, lr_threshold, out_start, disparity, confidence,
                   right_best, right_key):
        """Aggregate image rows ``first, first + sign, ...`` (up to ``stop``, exclusive).

        One sweep (``sign`` = +1 down, −1 up) of the path directions ``groups`` (see
        :func:`path_groups`) over the strip of rows ``lo .. hi`` (paths start at its
        edges), with penalties P1 and ``p2_table[|ΔI|]`` (:func:`adapted_p2_table`, the
        guide image's grey-level step along the path).  The window-summed cost of each
        row comes from ``source`` (see :func:`demtool.sgm.cost.advance_window`, window
        radius ``radius``).  The state
        (``buf``, ``mins``, ``ring``, ``running``, ``window_state``; see
        :func:`new_sweep_state`) carries over between calls, so a sweep may be split into
        consecutive calls.  What happens to each row's sum of path costs ``mode``:
        MODE_STORE writes it to ``total[y − total_base]``, MODE_ADD adds it there,
        MODE_FINISH adds the stored sum and, for rows ``out_start .. out_start +
        len(disparity)``, selects the disparity into ``disparity`` and ``confidence`` (see
        :func:`demtool.sgm.disparity.select_row`); MODE_DISCARD drops it (a sweep that
        only carries its paths through rows whose sums are formed later by a restarted
        sweep, see :func:`demtool.sgm.strips.match_strip`).
        """
        if callee_digest == "":  # never: it puts the digest into numba's cache key
            return
        width = guide.shape[1]
        n_groups = groups.shape[0]
        n_dirs = 4 * n_groups
        n_slots = buf.shape[0] - 1
        zero_slot = n_slots
        previous_slot = np.empty(n_dirs, dtype=np.int64)
        column_step = np.empty(n_dirs, dtype=np.int64)
        penalty = np.empty((n_dirs, width), dtype=np.int64)
        p1s = np.int16(p1)
        n_out = disparity.shape[0]
        n_disp = running.shape[1]
        y = first
        while y != stop:
            advance_window(source, y, sign, radius, ring, running, pixel, window_state)
            slot = y % n_slots
            # per row and direction: where L_r(p − r) is, and P2 for every pixel (adapted to
            # the guide image's step along the path); predecessors outside the strip or the
            # image fall on the all-zero slot or padding, so the path starts there (L_r = C)
            for j in range(n_dirs):
                dy = groups[j // 4, j % 4, 0]
                yp = y - sign * dy
                if dy == 0:
                    previous_slot[j] = slot
                elif yp >= lo and yp < hi:
                    previous_slot[j] = yp % n_slots
                else:
                    previous_slot[j] = zero_slot
                step = -sign * groups[j // 4, j % 4, 1]
                column_step[j] = step
                for x in range(width):
                    xp = x + step
                    if previous_slot[j] != zero_slot and 0 <= xp < width:
                        grey_step = abs(np.int32(guide[y, x]) - np.int32(guide[yp, xp]))
                        penalty[j, x] = p2_table[grey_step]
                    else:
                        penalty[j, x] = p2_table[0]
            # group 0 writes (a literal flag: no load of out), the others add
            out = total[y - total_base] if mode == MODE_STORE else scratch
            if n_disp >= LANES:
                _paths_rows(buf, mins, running, out, penalty, n_groups, slot, previous_slot,
                            column_step, sign, p1)
            else:
                for i in range(width):
                    x = i if sign > 0 else width - 1 - i
                    col = x + PAD
                    for g in range(n_groups):
                        j = 4 * g
                        # group 0 writes, the others add (a run-time flag: literal flags
                        # compiled _four_paths twice, 1-1.5 CPU s more on a fresh install)
                        _four_paths(buf, mins, j, slot, col,
                                    previous_slot[j], col + column_step[j], penalty[j, x],
                                    previous_slot[j + 1], col + column_step[j + 1],
                                    penalty[j + 1, x],
                                    previous_slot[j + 2], col + column_step[j + 2],
                                    penalty[j + 2, x],
                                    previous_slot[j + 3], col + column_step[j + 3],
                                    penalty[j + 3, x],
                                    running, x, p1s, out, g > 0)
            if mode == MODE_ADD:
                stored = total[y - total_base]
                for x in range(width):
                    for k in range(scratch.shape[1]):
                        stored[x, k] = np.uint16(stored[x, k] + scratch[x, k])
            elif mode == MODE_FINISH:
                stored = total[y - total_base]
                for x in range(width):
                    for k in range(scratch.shape[1]):
                        scratch[x, k] = np.uint16(scratch[x, k] + stored[x, k])
                if out_start <= y < out_start + n_out:
                    select_row(scratch, y, source[9], subpixel, lr_threshold, source[7],
                               source[8], right_best, right_key, disparity[y - out_start],
                               confidence[y - out_start])
            y += sign

    return sweep_rows


sweep_rows = _define_sweep_rows(callee_sources_digest())


@dataclass
class SweepState:
    """Buffers of one sweep (see :func:`sweep_rows`); reused across its calls."""

    buf: np.ndarray
    mins: np.ndarray
    ring: np.ndarray
    running: np.ndarray
    pixel: np.ndarray
    window_state: np.ndarray
    scratch: np.ndarray
    right_best: np.ndarray
    right_key: np.ndarray

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in vars(self).values())


def _aligned_zeros(shape, dtype, alignment=64, skew=0):
    """np.zeros whose data start ``skew`` bytes before a multiple of ``alignment``."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    raw = np.zeros(size + alignment, dtype=np.uint8)
    start = (-raw.ctypes.data - skew) % alignment
    return raw[start:start + size].view(dtype).reshape(shape)


def padded_disparities(num_disparities: int) -> int:
    """Length of a path-buffer column: D + 2 sentinels rounded up to a multiple of 16
    (see :func:`new_sweep_state`)."""
    return -(-(num_disparities + 2) // LANES) * LANES


def new_sweep_state(width: int, num_disparities: int, paths: int, radius: int) -> SweepState:
    """Fresh buffers for a sweep over rows of ``width`` pixels.

    Path costs: ring slots (2, or 3 for the 16-path knight moves, plus an all-zero slot
    for paths that start on this row) × directions × (W + 2·PAD) columns (zero padding:
    paths entering from outside the image start there) × (D + 2 sentinels, rounded up
    to a multiple of 16: every column's disparity 1 starts a 32-byte vector, so the
    path update's stores and centre loads are aligned; 11 % faster aggregation at 128
    disparities than unaligned columns of D + 2).  The cost and sum rows start on
    64-byte boundaries.
    """
    n_slots = 3 if paths == 16 else 2
    n_dirs = 4 * path_groups(paths).shape[0]
    columns = width + 2 * PAD
    # disparity 1 of every column on a 32-byte boundary: columns of a multiple of 16
    # int16, the array starting 2 bytes before a 64-byte boundary
    padded = padded_disparities(num_disparities)
    buf = _aligned_zeros((n_slots + 1, n_dirs, columns, padded), np.int16, skew=2)
    buf[:n_slots, :, PAD:PAD + width, 0] = SENTINEL
    buf[:n_slots, :, PAD:PAD + width, num_disparities + 1] = SENTINEL
    return SweepState(
        buf=buf, mins=np.zeros((n_slots + 1, n_dirs, columns), dtype=np.int16),
        ring=_aligned_zeros((2 * radius + 1, width, num_disparities), np.uint16),
        running=_aligned_zeros((width, num_disparities), np.uint16),
        pixel=_aligned_zeros((width, num_disparities), np.uint16),
        window_state=np.zeros(2, dtype=np.int64),
        scratch=_aligned_zeros((width, num_disparities), np.uint16),
        right_best=np.zeros(width, dtype=np.int16), right_key=np.zeros(width, dtype=np.uint32))


def check_penalties(p1: int, p2: int, paths: int, max_cost: int) -> None:
    """Raise ValueError unless 0 < P1 ≤ P2 and every sum fits the int16/uint16 buffers."""
    if not 0 < p1 <= p2:
        raise ValueError(f"penalties must satisfy 0 < P1 <= P2, got P1={p1}, P2={p2}")
    if p1 > MAX_P1:
        raise ValueError(f"P1={p1} is too large (at most {MAX_P1})")
    bound = int(max_cost) + int(p2)
    if paths * bound > np.iinfo(np.uint16).max or bound > SENTINEL:
        raise ValueError(f"cost maximum + P2 = {bound} is too large for {paths} paths "
                         f"(at most {np.iinfo(np.uint16).max // paths}); lower P2 or the "
                         "cost window")


def aggregate_costs(cost: np.ndarray, *, p1: int, p2: int, paths: int = 8,
                    guide: np.ndarray | None = None, p2_kappa: int = 0,
                    max_cost: int | None = None) -> np.ndarray:
    """Semi-global aggregation of a given cost volume along ``paths`` directions.

    Hirschmüller (2008), eqs. 13–14.  The SGM itself never holds a cost volume (its
    sweeps compute the cost rows on the fly); this is the same kernel fed from a
    volume, for inspection and tests.

    Parameters
    ----------
    cost : (H, W, D) uint16
        Matching cost C(p, d).
    p1, p2 : int
        Penalties for a disparity change of one pixel and of more, in cost units
        (``0 < p1 <= p2``).
    paths : {8, 16}
        Number of path directions.
    guide : (H, W) uint8, optional
        Left image grey levels, for the adaptive P2 (needed when ``p2_kappa > 0``).
    p2_kappa : int
        Grey-level step κ above which P2 is reduced (P2·κ/|ΔI|, at least P1);
        0 = constant P2.
    max_cost : int, optional
        An upper bound of ``cost`` (saves a pass over the volume when known).

    Returns
    -------
    (H, W, D) uint16, S(p, d) = Σ_r L_r(p, d).

    Raises
    ------
    ValueError
        Penalties out of range, or sums that could overflow uint16.
    """
    if cost.ndim != 3 or cost.dtype != np.uint16:
        raise ValueError(f"cost must be an (H, W, D) uint16 volume, got {cost.dtype} {cost.shape}")
    groups = path_groups(paths)
    check_penalties(p1, p2, paths,
                    int(cost.max(initial=0)) if max_cost is None else int(max_cost))
    if p2_kappa > 0 and guide is None:
        raise ValueError("adaptive P2 needs the guide image")
    height, width, n_disp = cost.shape
    if guide is None:
        guide = np.zeros((height, width), dtype=np.uint8)
    guide = np.ascontiguousarray(guide, dtype=np.uint8)
    source = volume_source(cost)
    total = np.empty(cost.shape, dtype=np.uint16)
    no_rows = np.empty((0, width), dtype=np.float32)
    for sign, mode in ((1, MODE_STORE), (-1, MODE_ADD)):
        state = new_sweep_state(width, n_disp, paths, 0)
        first, stop = (0, height) if sign > 0 else (height - 1, -1)
        sweep_rows(source, 0, guide, groups, int(p1), adapted_p2_table(p1, p2, p2_kappa), sign,
                   first, stop, 0, height, state.buf, state.mins, state.ring, state.running,
                   state.pixel, state.window_state, mode, total, 0, state.scratch, 0, -1, 0,
                   no_rows, no_rows, state.right_best, state.right_key)
    return total
