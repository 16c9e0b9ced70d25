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
    origin : (N, 3) float64 or None
        With ``origins``: the origin of each point's imaging ray, body-fixed metres.
    max_origin_miss_m : float
        Largest distance of an interpolated origin from the exact ray of its check
        point, metres (0 without origins).
    """

    line: np.ndarray
    sample: np.ndarray
    max_error_px: float
    exact_points: int
    origin: np.ndarray | None = None
    max_origin_miss_m: float = 0.0


@njit(cache=True, nogil=True)
def _interpolate_points(node_values, levels, rows, cols, heights, step, out):
    """Bilinear across the node lattice, Lagrange across the height levels, at points.

    node_values : (L, nr, nc, K), node (i, j) at lattice cell (i·step, j·step), K values
    each (line, sample[, ray origin x, y, z]); levels : (L,); rows, cols : (N,) cells
    from the lattice origin; heights : (N,); out : (N, K).
    """
    n_levels = levels.shape[0]
    nr, nc, n_values = node_values.shape[1], node_values.shape[2], node_values.shape[3]
    for p in range(rows.shape[0]):
        z = heights[p]
        fi = rows[p] / step
        i0 = min(max(int(math.floor(fi)), 0), nr - 2)
        ti = fi - i0
        fj = cols[p] / step
        j0 = min(max(int(math.floor(fj)), 0), nc - 2)
        tj = fj - j0
        for v in range(n_values):
            out[p, v] = 0.0
        for k in range(n_levels):
            weight = 1.0
            for m in range(n_levels):
                if m != k:
                    weight *= (z - levels[m]) / (levels[k] - levels[m])
            for v in range(n_values):
                a = node_values[k, i0, j0, v]
                b = node_values[k, i0, j0 + 1, v]
                c = node_values[k, i0 + 1, j0, v]
                d = node_values[k, i0 + 1, j0 + 1, v]
                out[p, v] += weight * ((1 - ti) * ((1 - tj) * a + tj * b)
                                       + ti * ((1 - tj) * c + tj * d))


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
           heights: np.ndarray, origins: bool) -> np.ndarray:
    """(N, 2) exact (line, sample) of cells, or (N, 5) with the origin of the ray
    through that pixel (``sensor.image_to_ray``)."""
    from demtool.maps import map_to_xyz

    t = transform  # the centre of cell (r, c) is at pixel (c + 0.5, r + 0.5)
    x = t.a * (cols + 0.5) + t.b * (rows + 0.5) + t.c
    y = t.d * (cols + 0.5) + t.e * (rows + 0.5) + t.f
    xyz = np.asarray(map_to_xyz(crs, x, y, heights), dtype=np.float64).reshape(-1, 3)
    line, sample = sensor.ground_to_image(xyz)
    if not origins:
        return np.column_stack([line, sample])
    with np.errstate(invalid="ignore"):
        origin = np.asarray(sensor.image_to_ray(line, sample).origin).reshape(-1, 3)
    return np.column_stack([line, sample, origin])


def _strip(sensor: Any, crs: Any, transform: Any, rows: np.ndarray, cols: np.ndarray,
           heights: np.ndarray, *, step: int, tolerance: float, check_points: int,
           rng: np.random.Generator, origins: bool) -> tuple[np.ndarray, float, float, int]:
    """(values (n, 2 or 5), max error px, max origin miss m, exact count) of one strip's
    points (finite heights)."""
    n = rows.size
    levels = height_levels(float(heights.min()), float(heights.max()))
    r_origin, c_origin = math.floor(rows.min()), math.floor(cols.min())
    span_r, span_c = rows.max() - r_origin, cols.max() - c_origin
    check = np.unique(rng.integers(0, n, min(check_points, n)))
    exact_check = None
    while step >= 2 and tolerance > 0:
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
        found = _exact(sensor, crs, transform, np.concatenate(all_r), np.concatenate(all_c),
                       np.concatenate(all_h), origins)
        if exact_check is None:
            exact_check = found[nodes:]
        node_values = np.ascontiguousarray(found[:nodes].reshape(
            (len(levels), n_r, n_c, found.shape[1])))
        rel_r, rel_c = rows - r_origin, cols - c_origin
        got = np.empty((check.size, found.shape[1]))
        _interpolate_points(node_values, levels, rel_r[check], rel_c[check], heights[check],
                            float(step), got)
        both = np.isfinite(exact_check[:, 0]) & np.isfinite(got[:, 0])
        error = float(np.max(np.hypot(got[both, 0] - exact_check[both, 0],
                                      got[both, 1] - exact_check[both, 1]), initial=0.0))
        if error <= tolerance:
            values = np.empty((n, found.shape[1]))
            _interpolate_points(node_values, levels, rel_r, rel_c, heights, float(step),
                                values)
            values[check] = exact_check
            # next to a node that did not converge: the exact projection decides
            redo = np.flatnonzero(~np.isfinite(values).all(axis=1))
            if redo.size:
                values[redo] = _exact(sensor, crs, transform, rows[redo], cols[redo],
                                      heights[redo], origins)
            return values, error, _origin_miss(sensor, got, exact_check, both), \
                int(check.size + redo.size)
        step //= 2
    return _exact(sensor, crs, transform, rows, cols, heights, origins), 0.0, 0.0, n


def _origin_miss(sensor: Any, got: np.ndarray, exact: np.ndarray, both: np.ndarray
                 ) -> float:
    """Largest distance (metres) of an interpolated ray origin from the exact ray of its
    check point (0 without origins)."""
    if got.shape[1] < 5 or not both.any():
        return 0.0
    with np.errstate(invalid="ignore"):
        ray = sensor.image_to_ray(exact[both, 0], exact[both, 1])
    direction = np.asarray(ray.direction).reshape(-1, 3)
    offset = got[both, 2:] - np.asarray(ray.origin).reshape(-1, 3)
    across = offset - np.sum(offset * direction, axis=1)[:, None] * direction
    miss = np.linalg.norm(across, axis=1)
    return float(np.max(miss[np.isfinite(miss)], initial=0.0))


def points_image_coordinates(sensor: Any, crs: Any, transform: Any, rows: np.ndarray,
                             cols: np.ndarray, heights: np.ndarray, *,
                             tolerance: float = TOLERANCE_PX, step: int = LATTICE_STEP,
                             strip_rows: int = STRIP_ROWS, check_points: int = CHECK_POINTS,
                             seed: int = 0, threads: int | None = None,
                             origins: bool = False) -> PointCoordinates:
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
    origins : bool
        Also the origin of each point's imaging ray (``sensor.image_to_ray`` at its
        pixel: a line scanner's position at the line's exposure), interpolated on the
        same lattice.

    Returns
    -------
    PointCoordinates
    """
    from demtool.mapproject.threads import ordered_map, warm

    rows = np.asarray(rows, dtype=np.float64).ravel()
    cols = np.asarray(cols, dtype=np.float64).ravel()
    heights = np.asarray(heights, dtype=np.float64).ravel()
    values = np.full((rows.size, 5 if origins else 2), np.nan)
    good = np.flatnonzero(np.isfinite(heights) & np.isfinite(rows) & np.isfinite(cols))
    if not good.size:
        return _result(values, 0.0, 0.0, 0)
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
        return _strip(sensor, crs, transform, rows[index], cols[index], heights[index],
                      step=max(int(step), 1), tolerance=tolerance,
                      check_points=check_points, rng=np.random.default_rng((seed, k)),
                      origins=origins)

    max_error, max_miss, exact = 0.0, 0.0, 0
    for (_, a, b), (found, error, miss, n_exact) in zip(
            pieces, ordered_map(one, pieces, threads=threads), strict=True):
        values[good[a:b]] = found
        max_error, max_miss = max(max_error, error), max(max_miss, miss)
        exact += n_exact
    return _result(values, max_error, max_miss, exact)


def _result(values: np.ndarray, error: float, miss: float, exact: int) -> PointCoordinates:
    origin = np.ascontiguousarray(values[:, 2:]) if values.shape[1] == 5 else None
    return PointCoordinates(np.ascontiguousarray(values[:, 0]),
                            np.ascontiguousarray(values[:, 1]), error, exact, origin, miss)


__all__ = ["CHECK_POINTS", "LATTICE_STEP", "STRIP_ROWS", "TOLERANCE_PX", "PointCoordinates",
           "height_levels", "points_image_coordinates"]
