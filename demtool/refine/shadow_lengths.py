"""Shadow lengths as height constraints for shape from shading ("shape from shadows").

A shadowed pixel carries no shading, but the shadow's length does carry height: along
a line toward the sun, the first lit pixel after a shadow (A, down-sun) sees the sun
just past the pixel where the shadow begins (E, the casting crest), so

    z(E) − z(A) = d(A, E) · tan(sun elevation)

with d the horizontal distance — the shadow-length measurement of heights and crater
depths (e.g. Chappelow & Sharpton 2002, *An improved shadow measurement technique
for constraining the morphometry of simple impact craters*, Meteorit. Planet. Sci.
37, 479–486).  Without it a shadow's interior is tied to the lit
ground only by integrability, and on a low sun (15°: half the grid in shadow) the
height drop across each shadow stays the coarse DEM's.

In the SfS energy each such segment adds ``ω (aᵀ(p, q) − t)²``: ``aᵀ(p, q)`` is the
height change from A to E summed from the slopes of the pixels on the line
(trapezoid rule), ``t`` the shadow-length height, both in units of the x pixel
spacing.  The term is quadratic in (p, q), so the slope step takes it exactly: per
segment a rank-one update of the per-pixel Gauss–Newton systems (Sherman–Morrison).
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from demtool.refine.shading import Illumination


class ShadowSegments(NamedTuple):
    """Shadow crossings along sun lines, flattened (segment i owns entries
    ``starts[i]:starts[i+1]``).

    Attributes
    ----------
    starts : (S + 1,) int64
    rows, cols : (M,) int64
        Pixels of the entries (A first, E last).
    coef_p, coef_q : (M,) float32
        ``a``: height change (x-pixel units) per unit of p and of q at that pixel.
    target : (S,) float32
        Shadow-length height ``z(E) − z(A)`` in x-pixel units.
    """

    starts: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    coef_p: np.ndarray
    coef_q: np.ndarray
    target: np.ndarray

    @property
    def count(self) -> int:
        return int(self.target.size)


@nb.njit(cache=True, nogil=True)
def _trace(dark: np.ndarray, lit: np.ndarray, step_row: float, step_col: float,
           max_steps: int, fill: bool, starts: np.ndarray, rows: np.ndarray,
           cols: np.ndarray, steps: np.ndarray) -> tuple[int, int]:  # pragma: no cover
    height, width = dark.shape
    segments = 0
    entries = 0
    for r in range(height):
        for c in range(width):
            if not lit[r, c]:
                continue
            # the pixel one step toward the sun must be in shadow
            r1 = int(np.floor(r + step_row + 0.5))
            c1 = int(np.floor(c + step_col + 0.5))
            if r1 < 0 or c1 < 0 or r1 >= height or c1 >= width or not dark[r1, c1]:
                continue
            end = -1
            for k in range(2, max_steps):
                rk = int(np.floor(r + k * step_row + 0.5))
                ck = int(np.floor(c + k * step_col + 0.5))
                if rk < 0 or ck < 0 or rk >= height or ck >= width:
                    break
                if lit[rk, ck]:
                    end = k
                    break
                if not dark[rk, ck]:
                    break  # no data: the crossing is not seen whole
            if end < 0:
                continue
            if fill:
                starts[segments] = entries
                steps[segments] = end
                for k in range(end + 1):
                    rows[entries + k] = int(np.floor(r + k * step_row + 0.5))
                    cols[entries + k] = int(np.floor(c + k * step_col + 0.5))
            segments += 1
            entries += end + 1
    if fill:
        starts[segments] = entries
    return segments, entries


def shadow_segments(dark: np.ndarray, usable: np.ndarray, spacing: tuple[float, float],
                    illumination: Illumination, *, max_length_px: int | None = None
                    ) -> ShadowSegments:
    """Trace every shadow crossing along sun lines (see the module docstring).

    Parameters
    ----------
    dark : (H, W) bool
        Shadowed pixels (from the image: :func:`demtool.refine.shadows.dark_pixels`).
    usable : (H, W) bool
        Pixels with image data; a crossing through a pixel without data is dropped.
    spacing : (dx, dy)
        Pixel spacing, metres.
    illumination : Illumination
        Sun direction (grid frame).
    max_length_px : int, optional
        Longest crossing traced, in steps of one pixel (default: the grid's larger side).

    Returns
    -------
    ShadowSegments
        Empty when the sun is at the zenith or nothing is in shadow.
    """
    dark = np.ascontiguousarray(dark, dtype=bool)
    lit = np.ascontiguousarray(usable, dtype=bool) & ~dark
    sx, sy, sz = (float(v) for v in illumination.sun)
    horizontal = float(np.hypot(sx, sy))
    empty = ShadowSegments(np.zeros(1, np.int64), np.zeros(0, np.int64),
                           np.zeros(0, np.int64), np.zeros(0, np.float32),
                           np.zeros(0, np.float32), np.zeros(0, np.float32))
    if horizontal < 1e-9 or not dark.any() or not lit.any():
        return empty
    dx, dy = float(spacing[0]), float(spacing[1])
    per_metre_col = sx / horizontal / dx
    per_metre_row = -sy / horizontal / dy  # y up = rows decreasing
    metres_per_step = 1.0 / max(abs(per_metre_col), abs(per_metre_row))
    step_col = per_metre_col * metres_per_step
    step_row = per_metre_row * metres_per_step
    longest = int(max_length_px or max(dark.shape)) + 2
    dummy_i = np.zeros(1, np.int64)
    count, size = _trace(dark, lit, step_row, step_col, longest, False, dummy_i, dummy_i,
                         dummy_i, dummy_i)
    if count == 0:
        return empty
    starts = np.zeros(count + 1, np.int64)
    rows = np.zeros(size, np.int64)
    cols = np.zeros(size, np.int64)
    steps = np.zeros(count, np.int64)
    _trace(dark, lit, step_row, step_col, longest, True, starts, rows, cols, steps)
    # height change per step in x-pixel units: Δz/dx = p Δcol − q Δrow · dy/dx
    per_step_p = step_col
    per_step_q = -step_row * dy / dx
    trapezoid = np.ones(size, np.float32)
    trapezoid[starts[:-1]] = 0.5
    trapezoid[starts[1:] - 1] = 0.5
    rise_per_metre = sz / horizontal
    target = (steps * metres_per_step * rise_per_metre / dx).astype(np.float32)
    return ShadowSegments(starts, rows, cols, (trapezoid * per_step_p).astype(np.float32),
                          (trapezoid * per_step_q).astype(np.float32), target)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _residuals(p: np.ndarray, q: np.ndarray, starts: np.ndarray, rows: np.ndarray,
               cols: np.ndarray, coef_p: np.ndarray, coef_q: np.ndarray,
               target: np.ndarray, out: np.ndarray, first: int,
               stop: int) -> None:  # pragma: no cover - compiled
    for s in range(first, stop):  # each segment's sum in order
        total = 0.0
        for j in range(starts[s], starts[s + 1]):
            total += coef_p[j] * p[rows[j], cols[j]] + coef_q[j] * q[rows[j], cols[j]]
        out[s] = total - target[s]


def segment_residuals(p: np.ndarray, q: np.ndarray, segments: ShadowSegments) -> np.ndarray:
    """``aᵀ(p, q) − t`` per segment (x-pixel units), (S,) float64; the segments in
    contiguous parts on every core (:func:`demtool.tiling.rows.on_row_parts`), each
    segment's sum in order as on one thread."""
    from demtool.tiling.rows import on_row_parts

    out = np.empty(segments.count, dtype=np.float64)
    on_row_parts(lambda first, stop: _residuals(
        p, q, segments.starts, segments.rows, segments.cols, segments.coef_p,
        segments.coef_q, segments.target, out, first, stop), segments.count)
    return out


@nb.njit(cache=True, nogil=True)
def _correct(p: np.ndarray, q: np.ndarray, p_new: np.ndarray, q_new: np.ndarray,
             Rp: np.ndarray, Rq: np.ndarray, weight: np.ndarray, c_total: float,
             omega: float, starts: np.ndarray, rows: np.ndarray, cols: np.ndarray,
             coef_p: np.ndarray, coef_q: np.ndarray,
             target: np.ndarray) -> None:  # pragma: no cover - compiled
    for s in range(target.size):
        residual = 0.0  # aᵀ(p, q) − t at the current slopes
        change = 0.0  # aᵀ Δ0, the step without this term
        curvature = 0.0  # aᵀ M⁻¹ a
        for j in range(starts[s], starts[s + 1]):
            r = rows[j]
            c = cols[j]
            ap = coef_p[j]
            aq = coef_q[j]
            residual += ap * p[r, c] + aq * q[r, c]
            change += ap * (p_new[r, c] - p[r, c]) + aq * (q_new[r, c] - q[r, c])
            w = weight[r, c]
            up = Rp[r, c]
            uq = Rq[r, c]
            k = w * (up * ap + uq * aq) / (c_total + w * (up * up + uq * uq))
            curvature += (ap * (ap - up * k) + aq * (aq - uq * k)) / c_total
        residual -= target[s]
        factor = omega * (residual + change) / (1.0 + omega * curvature)
        for j in range(starts[s], starts[s + 1]):
            r = rows[j]
            c = cols[j]
            ap = coef_p[j]
            aq = coef_q[j]
            w = weight[r, c]
            up = Rp[r, c]
            uq = Rq[r, c]
            k = w * (up * ap + uq * aq) / (c_total + w * (up * up + uq * uq))
            p_new[r, c] -= factor * (ap - up * k) / c_total
            q_new[r, c] -= factor * (aq - uq * k) / c_total


def independent_splits(segments: ShadowSegments, parts: int) -> np.ndarray:
    """Cuts of the segments into at most ``parts`` contiguous groups that share no pixel,
    as close to equal counts as such cuts allow: ``(G + 1,)`` int64 segment indices from
    0 to S.

    :func:`correct_slope_step` applies the segments in order, each one reading and
    updating the slope step at its pixels; groups with no pixel in common do not read
    what another writes, so they may run at the same time with the same numbers, to the
    bit, as one after the other.  A cut at k is allowed when no pixel belongs both to a
    segment before k and to one from k on.
    """
    count = segments.count
    parts = max(1, min(int(parts), count))
    if parts == 1:
        return np.array([0, count], np.int64)
    owner = np.repeat(np.arange(count, dtype=np.int64), np.diff(segments.starts))
    pixel = segments.rows * (int(segments.cols.max()) + 1) + segments.cols
    order = np.lexsort((owner, pixel))  # by pixel, then segment
    pixel, owner = pixel[order], owner[order]
    first_of_pixel = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
    last_of_pixel = np.r_[first_of_pixel[1:], pixel.size] - 1
    first, last = owner[first_of_pixel], owner[last_of_pixel]
    shared = last > first
    # a pixel of segments first … last forbids the cuts first + 1 … last
    blocked = np.zeros(count + 2, np.int64)
    np.add.at(blocked, first[shared] + 1, 1)
    np.add.at(blocked, last[shared] + 1, -1)
    allowed = np.flatnonzero(np.cumsum(blocked)[:count + 1] == 0)  # always 0 and count
    cuts = [0]
    for i in range(1, parts):
        best = int(allowed[np.argmin(np.abs(allowed - count * i // parts))])
        if cuts[-1] < best < count:
            cuts.append(best)
    cuts.append(count)
    return np.array(cuts, np.int64)


def correct_slope_step(p: np.ndarray, q: np.ndarray, p_new: np.ndarray, q_new: np.ndarray,
                       Rp: np.ndarray, Rq: np.ndarray, weight: np.ndarray, c_total: float,
                       omega: float, segments: ShadowSegments,
                       splits: np.ndarray | None = None) -> None:
    """Add ``ω Σ (aᵀ(p, q) − t)²`` to the slope step ``(p, q) → (p_new, q_new)`` in place.

    With M the per-pixel Gauss–Newton matrix ``c I + w u uᵀ`` of
    :func:`demtool.refine.kernels.slope_step` and Δ0 its step, the step of the energy
    with one more segment is ``Δ = Δ0 − M⁻¹a · ω (r + aᵀΔ0) / (1 + ω aᵀM⁻¹a)``
    (Sherman–Morrison), r the segment's current residual.  Exact for disjoint segments;
    segments sharing an end pixel are applied one after the other.  ``splits``
    (:func:`independent_splits`) cuts the segments into groups with no pixel in common,
    which run at once on every core (:func:`demtool.tiling.rows.on_row_parts`), each in
    order: the same numbers as one thread (default: one group).
    """
    if segments.count == 0 or omega <= 0:
        return
    if splits is None:
        splits = np.array([0, segments.count], np.int64)

    def groups(first: int, stop: int) -> None:
        begin, end = int(splits[first]), int(splits[stop])
        _correct(p, q, p_new, q_new, Rp, Rq, weight, float(c_total), float(omega),
                 segments.starts[begin:end + 1], segments.rows, segments.cols,
                 segments.coef_p, segments.coef_q, segments.target[begin:end])

    from demtool.tiling.rows import on_row_parts

    on_row_parts(groups, len(splits) - 1, min_rows=1)
