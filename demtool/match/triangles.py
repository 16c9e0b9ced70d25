"""Delaunay triangulation of seed matches: initial disparity and search bounds.

The seeds' left positions are triangulated (Delaunay, Qhull); inside a triangle the
initial disparity is the barycentric (linear) interpolation of its three vertices'
disparities, and the search range of the pixel is bounded by the smallest and
largest vertex disparity, widened by a margin — the self-adaptive
triangle-constrained matching of Wu et al. (2011, 2012) used for LRO NAC and
HiRISE.  Outside the convex hull of the seeds the nearest seeds stand in for a
triangle: the initial disparity is the nearest seed's, the range spans the
``k`` nearest seeds' disparities.

References
----------
Wu, B., Zhang, Y., Zhu, Q. (2011). A triangulation-based hierarchical image matching
    method for wide-baseline images. Photogramm. Eng. Remote Sens. 77(7), 695-708.
Wu, B., Zhang, Y., Zhu, Q. (2012). Integrated point and edge matching on poor
    textural images constrained by self-adaptive triangulations. ISPRS J. 68, 40-55.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from demtool.errors import ProcessingError

#: Largest raster (pixels, int32) of triangle indices built for integer query points.
RASTER_MAX_PIXELS = 64_000_000


@njit(cache=True)
def _barycentric_transforms(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Barycentric transform of each triangle, (M, 3, 2), as Qhull's ``transform``.

    ``out[t, :2]`` is the inverse of ``[[x0 − x2, x1 − x2], [y0 − y2, y1 − y2]]`` and
    ``out[t, 2]`` vertex 2, so that ``b = out[t, :2] @ (p − out[t, 2])`` gives the
    barycentric coordinates of vertices 0 and 1.  NaN for a degenerate triangle.
    (Computed here: scipy's ``Delaunay.transform`` takes seconds on large meshes.)
    """
    out = np.empty((simplices.shape[0], 3, 2))
    for t in range(simplices.shape[0]):
        x2 = points[simplices[t, 2], 0]
        y2 = points[simplices[t, 2], 1]
        a = points[simplices[t, 0], 0] - x2
        b = points[simplices[t, 1], 0] - x2
        c = points[simplices[t, 0], 1] - y2
        d = points[simplices[t, 1], 1] - y2
        det = a * d - b * c
        if abs(det) <= 1e-12 * max(1.0, abs(a * d) + abs(b * c)):
            out[t, :, :] = np.nan
            continue
        out[t, 0, 0] = d / det
        out[t, 0, 1] = -b / det
        out[t, 1, 0] = -c / det
        out[t, 1, 1] = a / det
        out[t, 2, 0] = x2
        out[t, 2, 1] = y2
    return out


@njit(cache=True)
def _rasterise(transform: np.ndarray, vertices: np.ndarray, x0: int, y0: int,
               out: np.ndarray) -> None:
    """Simplex index of every integer point of a grid (−1 outside every triangle).

    ``out[i, j]`` receives the triangle holding (x0 + j, y0 + i); ``transform`` is
    Qhull's barycentric transform (``Delaunay.transform``), ``vertices`` (M, 3, 2).
    A point on an edge shared by two triangles gets the first one (the interpolated
    disparity is continuous across it).
    """
    height, width = out.shape
    eps = 1e-9
    for t in range(transform.shape[0]):
        xmin = min(vertices[t, 0, 0], vertices[t, 1, 0], vertices[t, 2, 0])
        xmax = max(vertices[t, 0, 0], vertices[t, 1, 0], vertices[t, 2, 0])
        ymin = min(vertices[t, 0, 1], vertices[t, 1, 1], vertices[t, 2, 1])
        ymax = max(vertices[t, 0, 1], vertices[t, 1, 1], vertices[t, 2, 1])
        j0 = max(0, int(np.ceil(xmin - eps)) - x0)
        j1 = min(width - 1, int(np.floor(xmax + eps)) - x0)
        i0 = max(0, int(np.ceil(ymin - eps)) - y0)
        i1 = min(height - 1, int(np.floor(ymax + eps)) - y0)
        for i in range(i0, i1 + 1):
            dy = y0 + i - transform[t, 2, 1]
            for j in range(j0, j1 + 1):
                if out[i, j] >= 0:
                    continue
                dx = x0 + j - transform[t, 2, 0]
                b0 = transform[t, 0, 0] * dx + transform[t, 0, 1] * dy
                b1 = transform[t, 1, 0] * dx + transform[t, 1, 1] * dy
                if b0 >= -eps and b1 >= -eps and 1.0 - b0 - b1 >= -eps:
                    out[i, j] = t


@njit(cache=True)
def _barycentric(query: np.ndarray, simplex: np.ndarray, transform: np.ndarray,
                 simplices: np.ndarray, vertex_disparity: np.ndarray, disparity: np.ndarray,
                 low: np.ndarray, high: np.ndarray) -> None:
    """Barycentric disparity and vertex bounds of the points inside a triangle."""
    for k in range(query.shape[0]):
        t = simplex[k]
        if t < 0:
            continue
        dx = query[k, 0] - transform[t, 2, 0]
        dy = query[k, 1] - transform[t, 2, 1]
        b0 = transform[t, 0, 0] * dx + transform[t, 0, 1] * dy
        b1 = transform[t, 1, 0] * dx + transform[t, 1, 1] * dy
        d0 = vertex_disparity[simplices[t, 0]]
        d1 = vertex_disparity[simplices[t, 1]]
        d2 = vertex_disparity[simplices[t, 2]]
        disparity[k] = b0 * d0 + b1 * d1 + (1.0 - b0 - b1) * d2
        low[k] = min(d0, d1, d2)
        high[k] = max(d0, d1, d2)


class TriangleBounds(NamedTuple):
    """Initial disparity and search bounds at N query points.

    Attributes
    ----------
    disparity : (N,) float64
        Interpolated disparity (pixels, ``x_right = x_left − d``).
    low, high : (N,) float64
        Smallest and largest disparity of the enclosing triangle's vertices (or of the
        nearest seeds outside the hull), before any margin.
    inside : (N,) bool
        True where the point lies inside the seeds' convex hull.
    """

    disparity: np.ndarray
    low: np.ndarray
    high: np.ndarray
    inside: np.ndarray


class SeedTriangulation:
    """Delaunay triangulation of seed points carrying disparities.

    Parameters
    ----------
    points : (N, 2) float
        Seed positions (x, y) in the left image, pixels; N >= 3, not all collinear.
    disparity : (N,) float
        Seed disparities (pixels).
    outside_neighbours : int
        Seeds consulted for a query point outside the convex hull.

    Raises
    ------
    ProcessingError
        Fewer than 3 distinct seeds or all on one line (no triangle).
    """

    def __init__(self, points: np.ndarray, disparity: np.ndarray, *,
                 outside_neighbours: int = 3) -> None:
        from scipy.spatial import Delaunay, QhullError, cKDTree

        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        disparity = np.asarray(disparity, dtype=np.float64).reshape(-1)
        _, unique = np.unique(np.round(points, 3), axis=0, return_index=True)
        unique = np.sort(unique)
        self.points = points[unique]
        self.disparity = disparity[unique]
        if len(self.points) < 3:
            raise ProcessingError(f"only {len(self.points)} distinct seed match(es); at least "
                                  "3 are needed to triangulate the initial disparity")
        try:
            self.delaunay = Delaunay(self.points)
        except QhullError:
            raise ProcessingError(f"the {len(self.points)} seed matches are collinear; "
                                  "cannot triangulate the initial disparity") from None
        self.tree = cKDTree(self.points)
        self.outside_neighbours = min(int(outside_neighbours), len(self.points))
        self._raster: tuple[int, int, np.ndarray] | None = None  # (x0, y0, simplex grid)
        self.transform = _barycentric_transforms(self.points,
                                                 self.delaunay.simplices.astype(np.int64))

    def _find_simplex(self, query: np.ndarray) -> np.ndarray:
        """Triangle of each query point (−1 outside the hull).

        Integer points are looked up in a raster of the triangulation over their
        bounding box (numba, built once and reused while it covers the queries);
        other points (or a box over ``RASTER_MAX_PIXELS``) go through Qhull's
        ``find_simplex``.
        """
        if query.size == 0 or not np.all(query == np.round(query)):
            return self.delaunay.find_simplex(query)
        lo = query.min(axis=0).astype(np.int64)
        hi = query.max(axis=0).astype(np.int64)
        cached = self._raster
        if (cached is None or lo[0] < cached[0] or lo[1] < cached[1]
                or hi[0] >= cached[0] + cached[2].shape[1]
                or hi[1] >= cached[1] + cached[2].shape[0]):
            if (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) > RASTER_MAX_PIXELS:
                return self.delaunay.find_simplex(query)
            grid = np.full((int(hi[1] - lo[1]) + 1, int(hi[0] - lo[0]) + 1), -1, np.int32)
            _rasterise(self.transform, self.points[self.delaunay.simplices],
                       int(lo[0]), int(lo[1]), grid)
            cached = self._raster = (int(lo[0]), int(lo[1]), grid)
        x0, y0, grid = cached
        return grid[query[:, 1].astype(np.int64) - y0, query[:, 0].astype(np.int64) - x0]

    def __len__(self) -> int:
        return int(len(self.points))

    def neighbour_median(self) -> np.ndarray:
        """Median disparity of each seed's Delaunay neighbours, (N,) float64."""
        indptr, indices = self.delaunay.vertex_neighbor_vertices
        values = self.disparity[indices]
        out = np.empty(len(self.points))
        for i in range(len(self.points)):  # per seed, not per pixel
            out[i] = np.median(values[indptr[i]:indptr[i + 1]])
        return out

    def evaluate(self, x: np.ndarray, y: np.ndarray, *, chunk: int = 1 << 20) -> TriangleBounds:
        """Initial disparity and vertex-disparity bounds at query points.

        Parameters
        ----------
        x, y : (N,) float
            Query positions (column, row) in the left image, pixels.
        chunk : int
            Points per block (bounds the memory of the barycentric step).

        Returns
        -------
        TriangleBounds
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        y = np.asarray(y, dtype=np.float64).reshape(-1)
        disparity = np.empty(x.size)
        low = np.empty(x.size)
        high = np.empty(x.size)
        inside = np.empty(x.size, dtype=bool)
        for start in range(0, x.size, chunk):
            sl = slice(start, start + chunk)
            self._evaluate_block(np.column_stack([x[sl], y[sl]]), disparity[sl], low[sl],
                                 high[sl], inside[sl])
        return TriangleBounds(disparity, low, high, inside)

    def _evaluate_block(self, query: np.ndarray, disparity: np.ndarray, low: np.ndarray,
                        high: np.ndarray, inside: np.ndarray) -> None:
        simplex = self._find_simplex(query)
        inside[:] = simplex >= 0
        if inside.any():
            _barycentric(query, simplex, self.transform, self.delaunay.simplices,
                         self.disparity, disparity, low, high)
        outside = ~inside
        if outside.any():
            k = self.outside_neighbours
            _, nearest = self.tree.query(query[outside], k=k)
            nearest = nearest.reshape(-1, k)
            vertex_d = self.disparity[nearest]
            disparity[outside] = vertex_d[:, 0]
            low[outside] = vertex_d.min(axis=1)
            high[outside] = vertex_d.max(axis=1)
