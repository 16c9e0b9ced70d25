"""Semi-global cost aggregation along 8 or 16 image paths (Hirschmüller 2008, §3.1.3).

For each path direction r the cost is aggregated recursively (eq. 13):

    L_r(p, d) = C(p, d) + min(L_r(p − r, d),
                              L_r(p − r, d − 1) + P1,
                              L_r(p − r, d + 1) + P1,
                              min_i L_r(p − r, i) + P2) − min_k L_r(p − r, k)

and the aggregated cost is S(p, d) = Σ_r L_r(p, d) (eq. 14).  P2 can be adapted to
the intensity step along the path, P2 = max(P1, P2' · κ / max(|I_p − I_{p−r}|, κ)),
so depth discontinuities at intensity edges are cheaper (Hirschmüller 2008, §3.1.3).

The kernel sweeps the rows twice: top-down for the directions with a downward
component plus left-to-right, then bottom-up for the opposite directions plus
right-to-left.  Each sweep keeps only the last two rows (three for the 16-path
knight moves) of path costs per direction, so memory besides the cost and sum
volumes is O(W·D).  Costs are uint16,
path costs int16 (L ≤ C_max + P2) and the sum uint16 (≤ n_paths · (C_max + P2)).
The inner loop over disparities is branch-free so LLVM vectorises it (16 lanes of
int16 on AVX2).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# int16 sentinel for the path cost beyond the disparity range; SENTINEL + P1 must fit int16
SENTINEL = 16383
MAX_P1 = 16383

# Directions (dy, dx) with dy > 0; the sweeps add their opposites and the horizontals.
_DOWNWARD_8 = ((1, -1), (1, 0), (1, 1))
_DOWNWARD_16 = ((1, -2), (1, -1), (1, 0), (1, 1), (1, 2), (2, -1), (2, 1))


def downward_directions(paths: int) -> np.ndarray:
    """The path directions (dy, dx) with dy > 0 of an 8- or 16-path SGM, (n, 2) int64.

    The full set is these, their opposites and the two horizontal directions.
    """
    if paths == 8:
        return np.array(_DOWNWARD_8, dtype=np.int64)
    if paths == 16:
        return np.array(_DOWNWARD_16, dtype=np.int64)
    raise ValueError(f"paths must be 8 or 16, got {paths}")


@njit(nogil=True, cache=True, fastmath=True)
def _path_step(path, j, prev_slot, prev_x, slot, x, cost, y, cost_x, acc, p1, jump, prev_min):
    """One step of eq. 13 for all disparities, from L_r(p − r) to L_r(p); returns min_d L_r(p).

    ``path[j, slot, x]`` holds L_r of direction j, with int16 sentinels at both ends
    of the disparity axis; L_r(p, ·) is also added to ``acc``.  Everything is
    indexed on the full arrays (no array views in the hot loop, which would cost a
    reference-count update each), so the loop over d vectorises.  The cost is
    ``cost[y, cost_x]``.
    """
    n_disp = cost.shape[2]
    low = np.int16(32767)
    for k in range(1, n_disp + 1):
        best = min(path[j, prev_slot, prev_x, k],
                   np.int16(min(path[j, prev_slot, prev_x, k - 1],
                                path[j, prev_slot, prev_x, k + 1]) + p1))
        best = min(best, jump)
        value = np.int16(np.int16(cost[y, cost_x, k - 1]) + np.int16(best - prev_min))
        path[j, slot, x, k] = value
        acc[k - 1] = np.uint16(acc[k - 1] + np.uint16(value))
        low = min(low, value)
    return low


@njit(nogil=True, cache=True, fastmath=True)
def _path_start(path, j, slot, x, cost, y, cost_x, acc):
    """First pixel of a path: L_r(p, ·) = C(p, ·), added to ``acc``; returns its minimum."""
    n_disp = cost.shape[2]
    low = np.int16(32767)
    for k in range(n_disp):
        value = np.int16(cost[y, cost_x, k])
        path[j, slot, x, k + 1] = value
        acc[k] = np.uint16(acc[k] + cost[y, cost_x, k])
        low = min(low, value)
    return low


@njit(nogil=True, cache=True)
def _adapted_p2(p1, p2, kappa, guide, y, x, yp, xp):
    if kappa <= 0:
        return p2
    step = abs(np.int32(guide[y, x]) - np.int32(guide[yp, xp]))
    if step <= kappa:
        return p2
    return max(p1, (p2 * kappa) // step)


@njit(nogil=True, cache=True)
def _add_to_total(total, y, x, acc, first):
    n_disp = acc.shape[0]
    if first:
        for k in range(n_disp):
            total[y, x, k] = acc[k]
    else:
        for k in range(n_disp):
            total[y, x, k] = np.uint16(total[y, x, k] + acc[k])
    for k in range(n_disp):
        acc[k] = 0


@njit(nogil=True, cache=True, fastmath=True)
def _aggregate(cost, guide, directions, p1, p2, kappa, total):
    """Both sweeps of SGM over a cost volume; ``total`` receives S (overwritten)."""
    n_rows, width, n_disp = cost.shape
    n_dirs = directions.shape[0]
    n_slots = 2
    for j in range(n_dirs):
        n_slots = max(n_slots, directions[j, 0] + 1)
    # path costs of the last rows for each direction; a 2-slot buffer for the horizontal
    ring = np.full((max(n_dirs, 1), n_slots, width, n_disp + 2), SENTINEL, dtype=np.int16)
    ring_min = np.zeros((max(n_dirs, 1), n_slots, width), dtype=np.int16)
    line = np.full((1, 2, 1, n_disp + 2), SENTINEL, dtype=np.int16)
    acc = np.zeros(n_disp, dtype=np.uint16)
    p1s = np.int16(p1)
    for sweep in range(2):
        sign = 1 if sweep == 0 else -1
        for i in range(n_rows):
            y = i if sign == 1 else n_rows - 1 - i
            # horizontal path: left to right in the first sweep, right to left in the second
            x = 0 if sign == 1 else width - 1
            low = _path_start(line, 0, 0, 0, cost, y, x, acc)
            _add_to_total(total, y, x, acc, sweep == 0)
            current = 1
            for _ in range(1, width):
                xp = x
                x += sign
                p2e = _adapted_p2(p1, p2, kappa, guide, y, x, y, xp)
                low = _path_step(line, 0, 1 - current, 0, current, 0, cost, y, x, acc, p1s,
                                 np.int16(low + p2e), low)
                _add_to_total(total, y, x, acc, sweep == 0)
                current = 1 - current
            # the paths that come from the previous row(s)
            slot = y % n_slots
            for x in range(width):
                for j in range(n_dirs):
                    yp = y - sign * directions[j, 0]
                    xp = x - sign * directions[j, 1]
                    if yp < 0 or yp >= n_rows or xp < 0 or xp >= width:
                        ring_min[j, slot, x] = _path_start(ring, j, slot, x, cost, y, x, acc)
                    else:
                        p2e = _adapted_p2(p1, p2, kappa, guide, y, x, yp, xp)
                        prev_slot = yp % n_slots
                        prev_min = ring_min[j, prev_slot, xp]
                        ring_min[j, slot, x] = _path_step(ring, j, prev_slot, xp, slot, x, cost,
                                                          y, x, acc, p1s,
                                                          np.int16(prev_min + p2e), prev_min)
                _add_to_total(total, y, x, acc, False)


def aggregate_costs(cost: np.ndarray, *, p1: int, p2: int, paths: int = 8,
                    guide: np.ndarray | None = None, p2_kappa: int = 0,
                    max_cost: int | None = None) -> np.ndarray:
    """Semi-global aggregation of a cost volume along ``paths`` directions.

    Hirschmüller (2008), eqs. 13–14.

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
    if not 0 < p1 <= p2:
        raise ValueError(f"penalties must satisfy 0 < P1 <= P2, got P1={p1}, P2={p2}")
    if p1 > MAX_P1:
        raise ValueError(f"P1={p1} is too large (at most {MAX_P1})")
    bound = (int(cost.max(initial=0)) if max_cost is None else int(max_cost)) + p2
    if paths * bound > np.iinfo(np.uint16).max or bound > SENTINEL:
        raise ValueError(f"cost maximum + P2 = {bound} is too large for {paths} paths "
                         f"(at most {np.iinfo(np.uint16).max // paths}); lower P2 or the "
                         "cost window")
    if p2_kappa > 0 and guide is None:
        raise ValueError("adaptive P2 needs the guide image")
    if guide is None:
        guide = np.zeros((1, 1), dtype=np.uint8)
    total = np.empty(cost.shape, dtype=np.uint16)
    _aggregate(np.ascontiguousarray(cost), np.ascontiguousarray(guide, dtype=np.uint8),
               downward_directions(paths), int(p1), int(p2), int(p2_kappa), total)
    return total
