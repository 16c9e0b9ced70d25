"""Plane polygons of footprints: an equal-area projection, areas, exact intersections.

Pure numpy, vectorised over vertices; used by :mod:`demtool.camera.info`.

The intersection of two simple polygons A and B is measured without building it: the
boundary of A ∩ B is made of the parts of A's boundary inside B and the parts of B's
boundary inside A, so Green's theorem gives its area and centroid as sums over those
edge pieces (the shoelace terms of the polygon A ∩ B, in any order).  Every edge is cut
at its crossings with the other polygon's edges; a piece is kept when its midpoint is
inside the other polygon.  Pieces lying on the other polygon's boundary (shared edges)
are kept once: from A when both run the same way, from neither when they run opposite
ways.  Exact for simple (non-self-intersecting) polygons, convex or not, up to
rounding; O(n·m) for n and m vertices.
"""

from __future__ import annotations

import numpy as np

__all__ = ["laea_forward", "laea_inverse", "point_in_polygon", "polygon_area",
           "polygon_centroid", "polygon_intersection"]


def laea_forward(lon_deg, lat_deg, lon0_deg: float, lat0_deg: float, radius: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Lambert azimuthal equal-area projection on a sphere (Snyder 1987, eqs. 24-2–24-4).

    Parameters
    ----------
    lon_deg, lat_deg : array_like, degrees
        Planetocentric, east-positive coordinates.
    lon0_deg, lat0_deg : float, degrees
        Centre of the projection.
    radius : float
        Sphere radius, metres.

    Returns
    -------
    x, y : float64 arrays, metres (x east, y north at the centre); areas are preserved.

    References
    ----------
    J. P. Snyder, *Map Projections — A Working Manual*, USGS Professional Paper 1395
    (1987), pp. 182–190.
    """
    lam = np.radians(np.asarray(lon_deg, dtype=np.float64) - lon0_deg)
    phi = np.radians(np.asarray(lat_deg, dtype=np.float64))
    phi0 = np.radians(lat0_deg)
    cos_c = np.sin(phi0) * np.sin(phi) + np.cos(phi0) * np.cos(phi) * np.cos(lam)
    k = np.sqrt(2.0 / np.maximum(1.0 + cos_c, 1e-300))
    x = radius * k * np.cos(phi) * np.sin(lam)
    y = radius * k * (np.cos(phi0) * np.sin(phi) - np.sin(phi0) * np.cos(phi) * np.cos(lam))
    return x, y


def laea_inverse(x, y, lon0_deg: float, lat0_deg: float, radius: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`laea_forward` (Snyder 1987, eqs. 24-16, 20-14, 20-15).

    Returns
    -------
    lon_deg, lat_deg : float64 arrays, degrees (longitude in (−180, 180]).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    phi0 = np.radians(lat0_deg)
    rho = np.hypot(x, y)
    c = 2.0 * np.arcsin(np.clip(rho / (2.0 * radius), -1.0, 1.0))
    safe = np.where(rho > 0, rho, 1.0)
    phi = np.arcsin(np.clip(np.cos(c) * np.sin(phi0)
                            + np.where(rho > 0, y * np.sin(c) * np.cos(phi0) / safe, 0.0),
                            -1.0, 1.0))
    lam = np.arctan2(x * np.sin(c), rho * np.cos(phi0) * np.cos(c)
                     - y * np.sin(phi0) * np.sin(c))
    lon = (np.degrees(lam) + lon0_deg + 180.0) % 360.0 - 180.0
    return lon, np.degrees(phi)


def polygon_area(x, y) -> float:
    """Signed area of a closed polygon (shoelace), positive when counter-clockwise.

    x, y : (n,) vertices once around (the last joins the first), any unit.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_centroid(x, y) -> tuple[float, float]:
    """Centroid of a closed simple polygon (area-weighted, shoelace moments)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    area = 0.5 * cross.sum()
    return float(((x + x1) * cross).sum() / (6 * area)), float(((y + y1) * cross).sum()
                                                              / (6 * area))


def point_in_polygon(px, py, x, y) -> np.ndarray:
    """Even-odd test of points against a closed polygon (crossing number).

    px, py : (m,) points; x, y : (n,) vertices.  Points exactly on an edge may fall
    either way (see :func:`_on_boundary`).  Returns (m,) bool.
    """
    px = np.asarray(px, dtype=np.float64)[:, None]
    py = np.asarray(py, dtype=np.float64)[:, None]
    x1, y1 = np.asarray(x, dtype=np.float64)[None], np.asarray(y, dtype=np.float64)[None]
    x2, y2 = np.roll(x1, -1, axis=1), np.roll(y1, -1, axis=1)
    straddle = (y1 > py) != (y2 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
    return (np.sum(straddle & (px < x_cross), axis=1) % 2).astype(bool)


def _on_boundary(px, py, dx, dy, x, y, tol: float) -> np.ndarray:
    """Per point: +1 on an edge of (x, y) running along (dx, dy), −1 on one running
    the other way, 0 off the boundary (distance > tol)."""
    x1, y1 = x[None], y[None]
    ex, ey = np.roll(x1, -1, axis=1) - x1, np.roll(y1, -1, axis=1) - y1
    length2 = np.maximum(ex * ex + ey * ey, 1e-300)
    t = np.clip(((px[:, None] - x1) * ex + (py[:, None] - y1) * ey) / length2, 0.0, 1.0)
    dist = np.hypot(px[:, None] - x1 - t * ex, py[:, None] - y1 - t * ey)
    near = dist <= tol
    same = (dx[:, None] * ex + dy[:, None] * ey) > 0
    return np.where(np.any(near & same, axis=1), 1, np.where(np.any(near, axis=1), -1, 0))


def _inside_pieces(ax, ay, bx, by, tol: float, keep_shared: bool):
    """Green's-theorem sums (2·area, 6·area·cx, 6·area·cy) of A's edge pieces inside B."""
    px, py = ax, ay
    qx, qy = np.roll(ax, -1), np.roll(ay, -1)
    rx, ry = bx, by
    sx, sy = np.roll(bx, -1), np.roll(by, -1)
    d1x, d1y = (qx - px)[:, None], (qy - py)[:, None]
    d2x, d2y = (sx - rx)[None], (sy - ry)[None]
    wx, wy = rx[None] - px[:, None], ry[None] - py[:, None]
    denom = d1x * d2y - d1y * d2x
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wx * d2y - wy * d2x) / denom
        u = (wx * d1y - wy * d1x) / denom
    valid = (denom != 0) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    cuts = np.where(valid, t, np.nan)
    n = len(ax)
    cuts = np.sort(np.concatenate([np.zeros((n, 1)), cuts, np.ones((n, 1))], axis=1), axis=1)
    t0, t1 = cuts[:, :-1], cuts[:, 1:]
    use = np.isfinite(t1) & (t1 > t0)
    edge = np.broadcast_to(np.arange(n)[:, None], t0.shape)[use]
    t0, t1 = t0[use], t1[use]
    x0 = px[edge] + t0 * d1x[edge, 0]
    y0 = py[edge] + t0 * d1y[edge, 0]
    x1 = px[edge] + t1 * d1x[edge, 0]
    y1 = py[edge] + t1 * d1y[edge, 0]
    mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    boundary = _on_boundary(mx, my, d1x[edge, 0], d1y[edge, 0], bx, by, tol)
    inside = np.where(boundary == 0, point_in_polygon(mx, my, bx, by),
                      (boundary > 0) & keep_shared)
    cross = (x0 * y1 - x1 * y0)[inside]
    return (cross.sum(), ((x0 + x1)[inside] * cross).sum(), ((y0 + y1)[inside] * cross).sum())


def polygon_intersection(ax, ay, bx, by) -> tuple[float, tuple[float, float]]:
    """Area and centroid of the intersection of two simple polygons (see module doc).

    Parameters
    ----------
    ax, ay : (n,) float
        Vertices of A once around (either orientation), any unit.
    bx, by : (m,) float
        Vertices of B.

    Returns
    -------
    area : float
        Area of A ∩ B (units²), 0 when they do not overlap.
    centroid : (float, float)
        Its centroid, NaN when the area is 0.
    """
    ax, ay, bx, by = (np.asarray(v, dtype=np.float64) for v in (ax, ay, bx, by))
    if polygon_area(ax, ay) < 0:
        ax, ay = ax[::-1], ay[::-1]
    if polygon_area(bx, by) < 0:
        bx, by = bx[::-1], by[::-1]
    span = max(np.ptp(np.concatenate([ax, bx])), np.ptp(np.concatenate([ay, by])), 1e-300)
    tol = 1e-9 * span
    a = _inside_pieces(ax, ay, bx, by, tol, keep_shared=True)
    b = _inside_pieces(bx, by, ax, ay, tol, keep_shared=False)
    twice = a[0] + b[0]
    area = 0.5 * twice
    if area <= tol * tol:
        return 0.0, (float("nan"), float("nan"))
    return float(area), (float((a[1] + b[1]) / (3 * twice)), float((a[2] + b[2]) / (3 * twice)))
