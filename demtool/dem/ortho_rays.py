"""The two rays of each map-grid disparity between two orthoimages (``dem
--mapprojected``, untiled and in tiles).

The left cell (row, col) and the right cell (row + shift, col − d) are raised to the
surface each orthoimage was projected on; each such ground point is seen by one raw
pixel of its sensor (:func:`demtool.mapproject.stereo.raw_coordinates`, interpolated on
a lattice of exact projections within 0.0001 px), and that pixel's ray runs from its
origin (the sensor's position at the pixel's exposure, interpolated on the same
lattice) through the ground point (:func:`demtool.dem.sensors.triangulate_ground_rays`
intersects the two).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np


class OrthoRays(NamedTuple):
    """Raw coordinates and rays of the cells of a map-grid disparity.

    left, right : demtool.mapproject.lattice.PointCoordinates
        Raw (line, sample) and ray origins (N, 3) of each side's cells.
    ground_left, ground_right : (N, 3) float64
        The cells' points on each orthoimage's surface, body-fixed metres.
    seen : (N,) bool
        Cells seen by both sensors.
    """

    left: Any
    right: Any
    ground_left: np.ndarray
    ground_right: np.ndarray
    seen: np.ndarray

    def rays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(origin_left, ground_left, origin_right, ground_right) of the cells seen."""
        arrays = (self.left.origin, self.ground_left, self.right.origin, self.ground_right)
        if self.seen.all():  # usually: no copies
            return arrays
        return tuple(a[self.seen] for a in arrays)

    def max_error_px(self) -> float:
        return max(self.left.max_error_px, self.right.max_error_px)


def ortho_rays(left, right, crs, rows: np.ndarray, left_cols: np.ndarray,
               right_rows: np.ndarray, right_cols: np.ndarray) -> OrthoRays:
    """Raw coordinates and rays of each side's cells.

    Parameters
    ----------
    left, right : demtool.dem.inputs.Ortho
        The orthoimages (grid, sensor model, surface heights).
    crs : pyproj.CRS
        The orthoimages' map CRS.
    rows, left_cols : (N,) float
        The left cells.
    right_rows, right_cols : (N,) float
        The right cells (fractional).

    Returns
    -------
    OrthoRays
    """
    from demtool.mapproject.stereo import map_cells_xy, raw_coordinates
    from demtool.mapproject.threads import available_threads, batched, ordered_map
    from demtool.maps import map_to_xyz

    def ground(x, y, h):
        return (np.asarray(map_to_xyz(crs, x, y, h), dtype=np.float64).reshape(-1, 3),)

    def side(task):
        ortho, r, c = task
        x, y = map_cells_xy(ortho.info.transform, r, c)
        h = np.asarray(ortho.heights(x, y), dtype=np.float64)
        raw = raw_coordinates(ortho.sensor, crs, ortho.info.transform, r, c, h,
                              origins=True)
        return raw, batched(ground, x, y, h)[0]

    # the two sides at once, each on its share of the threads: their serial steps (the
    # cells' map x, y and heights, the strips' assembly) overlap too; each value is
    # computed as on one thread (strips and batches alone), so the same numbers
    (l_raw, l_ground), (r_raw, r_ground) = ordered_map(
        side, ((left, rows, left_cols), (right, right_rows, right_cols)),
        threads=min(2, available_threads()))
    seen = (np.isfinite(l_raw.line) & np.isfinite(l_raw.sample) & np.isfinite(r_raw.line)
            & np.isfinite(r_raw.sample))
    return OrthoRays(l_raw, r_raw, l_ground, r_ground, seen)


__all__ = ["OrthoRays", "ortho_rays"]
