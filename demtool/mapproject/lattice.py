"""Raw image coordinates of scattered map cells, interpolated on a lattice of exact
projections with a measured error bound.

``dem --mapprojected`` needs the raw image ``(line, sample)`` of every valid disparity's
left cell and right cell (fractional: ``col − d``) on the surface its orthoimage was
projected on.  Projecting each through a line scanner's ``ground_to_image`` (an iterative
search of the exposure line, ~3 µs a point) was most of the route's CPU.  As
``mapproject`` does for its tiles (:func:`demtool.mapproject.core.image_coordinates`),
the map → image function is smooth in map x, y and in the height, so within a strip of
map rows it is evaluated exactly on a lattice of nodes (every ``step`` cells) at one to
three heights spanning the strip's points, and interpolated at the points: bilinear
across the lattice, Lagrange across the heights.  The interpolation error is measured
against exact projections of random points of every strip; the lattice is halved
(down to exact projection of every point) until that error is at most ``tolerance``
pixels (default :data:`TOLERANCE_PX`, 0.0001 px).  Points whose lattice cell has a node
that does not converge are projected exactly, so the points seen are those an exact
projection sees.  ASP's map-projected stereo goes back to the raw cameras the same way
through its ``Map2CamTrans`` (Beyer, Alexandrov & McMichael 2018, *The Ames Stereo
Pipeline*, Earth and Space Science 5, §2.3).

The strips run on every core (:func:`demtool.mapproject.threads.ordered_map`); each is
computed as it would be alone (its check points drawn from a seed and its index), so the
result does not depend on the number of threads.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit, prange

#: largest interpolation error accepted at the check points, raw image pixels
TOLERANCE_PX = 1e-4
#: map rows per strip (a strip's lattice spans its points)
STRIP_ROWS = 128
#: first lattice spacing, map cells
LATTICE_STEP = 8
#: random points of each strip projected exactly to measure the interpolation error
CHECK_POINTS = 256


class PointCoordinates(NamedTuple):
    """Raw image coordinates of scattered map cells.

    line, sample : (N,) float64
        CSM image coordinates; NaN where unseen or no height.
    max_error_px : float
        Largest interpolation error found at the check points of any strip, pixels.
    exact_points : int
        Points (of N) projected exactly (strips where no lattice met the tolerance,
        points next to a node that does not converge, check points).
    """

    line: np.ndarray
    sample: np.ndarray
    max_error_px: float
    exact_points: int


@njit(cache=True, nogil=True)
def _interpolate_points(node_line, node_sample, levels, rows, cols, heights, step,
                        out_line, out_sample):
    """Bilinear across the node lattice, Lagrange across the height levels, at points.

    node_* : (L, nr, nc), node (i, j) at lattice cell (i·step, j·step); levels : (L,);
    rows, cols : (N,) cells from the lattice origin; heights : (N,); out_* : (N,).
    """
    n_levels = levels.shape[0]
    nr, nc = node_line.shape[1], node_line.shape[2]
    for p in range(rows.shape[0]):
        z = heights[p]
        fi = rows[p] / step
        i0 = min(max(int(math.floor(fi)), 0), nr - 2)
        ti = fi - i0
        fj = cols[p] / step
        j0 = min(max(int(math.floor(fj)), 0), nc - 2)
        tj = fj - j0
        acc_l = 0.0
        acc_s = 0.0
        for k in range(n_levels):
            weight = 1.0
            for m in range(n_levels):
                if m != k:
                    weight *= (z - levels[m]) / (levels[k] - levels[m])
            a = node_line[k, i0, j0]
            b = node_line[k, i0, j0 + 1]
            c = node_line[k, i0 + 1, j0]
            d = node_line[k, i0 + 1, j0 + 1]
            acc_l += weight * ((1 - ti) * ((1 - tj) * a + tj * b)
                               + ti * ((1 - tj) * c + tj * d))
            a = node_sample[k, i0, j0]
            b = node_sample[k, i0, j0 + 1]
            c = node_sample[k, i0 + 1, j0]
            d = node_sample[k, i0 + 1, j0 + 1]
            acc_s += weight * ((1 - ti) * ((1 - tj) * a + tj * b)
                               + ti * ((1 - tj) * c + tj * d))
        out_line[p] = acc_l
        out_sample[p] = acc_s


@njit(cache=True, parallel=True, nogil=True)
def _strip_starts(rows, first, strip_rows, count):
    """Index of each strip's first point in ``rows`` (sorted), and the end: (count + 1,)."""
    out = np.empty(count + 1, dtype=np.int64)
    for k in prange(count + 1):
        target = first + k * strip_rows
        lo, hi = 0, rows.shape[0]
        while lo < hi:  # first row ≥ target
            mid = (lo + hi) // 2
            if rows[mid] < target:
                lo = mid + 1
            else:
                hi = mid
        out[k] = lo
    out[count] = rows.shape[0]
    return out


def height_levels(low: float, high: float) -> np.ndarray:
    """The heights the lattice is projected at (as
    :func:`demtool.mapproject.core.image_coordinates`): one for a flat strip, its ends
    below 50 m of relief, ends and middle above."""
    if high - low < 1e-3:
        return np.array([low])
    if high - low < 50.0:
        return np.array([low, high])
    return np.array([low, 0.5 * (low + high), high])


def _exact(sensor: Any, crs: Any, transform: Any, rows: np.ndarray, cols: np.ndarray,
           heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from demtool.maps import map_to_xyz

    t = transform  # the centre of cell (r, c) is at pixel (c + 0.5, r + 0.5)
    x = t.a * (cols + 0.5) + t.b * (rows + 0.5) + t.c
    y = t.d * (cols + 0.5) + t.e * (rows + 0.5) + t.f
    xyz = np.asarray(map_to_xyz(crs, x, y, heights), dtype=np.float64).reshape(-1, 3)
    return sensor.ground_to_image(xyz)


def _strip(sensor: Any, crs: Any, transform: Any, rows: np.ndarray, cols: np.ndarray,
           heights: np.ndarray, *, step: int, tolerance: float, check_points: int,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float, int]:
    """(line, sample, max error, exact count) of one strip's points (finite heights)."""
    n = rows.size
    levels = height_levels(float(heights.min()), float(heights.max()))
    r_origin, c_origin = math.floor(rows.min()), math.floor(cols.min())
    span_r, span_c = rows.max() - r_origin, cols.max() - c_origin
    check = np.unique(rng.integers(0, n, min(check_points, n)))
    exact_check = None
    error = 0.0
    while step >= 2:
        n_r = max(int(math.ceil(span_r / step)) + 1, 2)
        n_c = max(int(math.ceil(span_c / step)) + 1, 2)
        nodes = len(levels) * n_r * n_c
        if nodes + check.size >= n:  # as many projections as the points: project them
            break
        node_r, node_c = np.meshgrid(r_origin + step * np.arange(n_r, dtype=np.float64),
                                     c_origin + step * np.arange(n_c, dtype=np.float64),
                                     indexing="ij")
        all_r = [np.tile(node_r.ravel(), len(levels))]
        all_c = [np.tile(node_c.ravel(), len(levels))]
        all_h = [np.repeat(levels, node_r.size)]
        if exact_check is None:  # the check points ride along with the first lattice
            all_r.append(rows[check])
            all_c.append(cols[check])
            all_h.append(heights[check])
        line_all, sample_all = _exact(sensor, crs, transform, np.concatenate(all_r),
                                      np.concatenate(all_c), np.concatenate(all_h))
        if exact_check is None:
            exact_check = line_all[nodes:], sample_all[nodes:]
        shape = (len(levels), n_r, n_c)
        node_line = np.ascontiguousarray(line_all[:nodes].reshape(shape))
        node_sample = np.ascontiguousarray(sample_all[:nodes].reshape(shape))
        rel_r, rel_c = rows - r_origin, cols - c_origin
        got_l, got_s = np.empty(check.size), np.empty(check.size)
        _interpolate_points(node_line, node_sample, levels, rel_r[check], rel_c[check],
                            heights[check], float(step), got_l, got_s)
        both = np.isfinite(exact_check[0]) & np.isfinite(got_l)
        error = float(np.max(np.hypot(got_l - exact_check[0], got_s - exact_check[1])[both],
                             initial=0.0))
        if error <= tolerance:
            line, sample = np.empty(n), np.empty(n)
            _interpolate_points(node_line, node_sample, levels, rel_r, rel_c, heights,
                                float(step), line, sample)
            line[check], sample[check] = exact_check
            # next to a node that did not converge: the exact projection decides
            redo = np.flatnonzero(~(np.isfinite(line) & np.isfinite(sample)))
            if redo.size:
                line[redo], sample[redo] = _exact(sensor, crs, transform, rows[redo],
                                                  cols[redo], heights[redo])
            return line, sample, error, int(check.size + redo.size)
        step //= 2
    line, sample = _exact(sensor, crs, transform, rows, cols, heights)
    return line, sample, 0.0, n


def points_image_coordinates(sensor: Any, crs: Any, transform: Any, rows: np.ndarray,
                             cols: np.ndarray, heights: np.ndarray, *,
                             tolerance: float = TOLERANCE_PX, step: int = LATTICE_STEP,
                             strip_rows: int = STRIP_ROWS, check_points: int = CHECK_POINTS,
                             seed: int = 0, threads: int | None = None) -> PointCoordinates:
    """Raw image coordinates of map cells on a surface (see the module docstring).

    Parameters
    ----------
    sensor : demtool.sensors.base.SensorModel
    crs, transform
        The map grid (projected CRS on the body's sphere) and its transform.
    rows, cols : (N,) float
        Cells (fractional allowed; the centre of cell (r, c) at pixel ``(c + 0.5,
        r + 0.5)`` of the transform).
    heights : (N,) float
        Surface heights at the cells, metres above the body's sphere; NaN = none.
    tolerance : float
        Largest interpolation error accepted at the check points, image pixels (0:
        every point projected exactly).
    step : int
        First lattice spacing, cells.
    strip_rows : int
        Map rows per strip.
    check_points : int
        Random points per strip projected exactly to measure the error.
    seed : int
        Seed of the check points (strip k draws from ``(seed, k)``).
    threads : int, optional
        Strips at once (default: every core).

    Returns
    -------
    PointCoordinates
    """
    from demtool.mapproject.threads import ordered_map, warm

    rows = np.asarray(rows, dtype=np.float64).ravel()
    cols = np.asarray(cols, dtype=np.float64).ravel()
    heights = np.asarray(heights, dtype=np.float64).ravel()
    line = np.full(rows.shape, np.nan)
    sample = np.full(rows.shape, np.nan)
    good = np.flatnonzero(np.isfinite(heights) & np.isfinite(rows) & np.isfinite(cols))
    if not good.size:
        return PointCoordinates(line, sample, 0.0, 0)
    r = rows[good]
    if r.size > 1 and np.any(r[1:] < r[:-1]):  # a disparity's cells come row by row
        good = good[np.argsort(r, kind="stable")]
        r = rows[good]
    first = math.floor(r[0])
    count = int((math.floor(r[-1]) - first) // strip_rows) + 1
    starts = _strip_starts(r, float(first), float(strip_rows), count)
    pieces = [(k, starts[k], starts[k + 1]) for k in range(count) if starts[k + 1] > starts[k]]
    warm(sensor)

    def one(piece):
        k, a, b = piece
        index = good[a:b]
        if tolerance <= 0:
            found = _exact(sensor, crs, transform, rows[index], cols[index], heights[index])
            return (*found, 0.0, b - a)
        return _strip(sensor, crs, transform, rows[index], cols[index], heights[index],
                      step=max(int(step), 1), tolerance=tolerance,
                      check_points=check_points, rng=np.random.default_rng((seed, k)))

    max_error, exact = 0.0, 0
    for (_, a, b), (s_line, s_sample, error, n_exact) in zip(
            pieces, ordered_map(one, pieces, threads=threads), strict=True):
        line[good[a:b]], sample[good[a:b]] = s_line, s_sample
        max_error, exact = max(max_error, error), exact + n_exact
    return PointCoordinates(line, sample, max_error, exact)


__all__ = ["CHECK_POINTS", "LATTICE_STEP", "STRIP_ROWS", "TOLERANCE_PX", "PointCoordinates",
           "height_levels", "points_image_coordinates"]
