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

from demtool.errors import ProcessingError


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
        simplex = self.delaunay.find_simplex(query)
        inside[:] = simplex >= 0
        if inside.any():
            s = simplex[inside]
            transform = self.delaunay.transform[s]  # (M, 3, 2): inverse T and offset r
            delta = query[inside] - transform[:, 2]
            bary2 = np.einsum("mij,mj->mi", transform[:, :2], delta)
            bary = np.column_stack([bary2, 1.0 - bary2.sum(axis=1)])
            vertex_d = self.disparity[self.delaunay.simplices[s]]
            disparity[inside] = np.sum(bary * vertex_d, axis=1)
            low[inside] = vertex_d.min(axis=1)
            high[inside] = vertex_d.max(axis=1)
        outside = ~inside
        if outside.any():
            k = self.outside_neighbours
            _, nearest = self.tree.query(query[outside], k=k)
            nearest = nearest.reshape(-1, k)
            vertex_d = self.disparity[nearest]
            disparity[outside] = vertex_d[:, 0]
            low[outside] = vertex_d.min(axis=1)
            high[outside] = vertex_d.max(axis=1)
