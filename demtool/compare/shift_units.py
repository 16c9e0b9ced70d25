"""A co-registration shift in the units users read: metres east/north/up and input pixels.

The aligners (:mod:`demtool.compare.align`) fit the shift in pixels of the comparison
grid — the reference's grid, the DEM's, or the metric grid a degree grid is measured on
(:func:`demtool.compare.planetary.metric_grid`), which no user has seen.  xdem and CNES
demcompare report the shift in the DEM's own pixels and in metres east/north; ASP's
``pc_align`` in metres.  This module turns the comparison grid's shift into those units.

The conversion is the shift's local linearisation at the comparison grid's centre:

* **metres** — the grid's centre and the centre moved by the shift are taken to
  longitude/latitude on the CRS's own datum, and the geodesic between them on the
  CRS's ellipsoid (``pyproj.Geod.inv``, Karney's algorithm) gives its length and azimuth:
  ``east = s sin(az)``, ``north = s cos(az)``.  True ground metres, whatever the map
  projection's scale or the grid's rotation.  A raster without CRS (an image frame, a
  local map) has no east or north: its shift is given in metres along the raster's own
  map axes ``x``, ``y`` (its transform's units, metres by demtool's contract).
* **input pixels** — both points are taken into each input raster's CRS (pyproj) and
  through the inverse of its transform: the difference is the shift in that raster's
  columns (x right) and rows (y down).  A raster on a degree grid (SRTM's 3″) is thus
  shifted in its own degree pixels.
* **uncertainty** — the one-sigma of ``dx_px`` and ``dy_px`` propagated through the
  same linear map (the Jacobian of one-pixel steps along x and y), treating the two as
  independent; ``dz`` is metres up already.

Sign: the shift is what was *added to the DEM* to align it (as ``shift`` in the report):
the DEM's content moved by ``east`` metres east and ``north`` metres north.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["shift_in_units"]


def _geodetic(crs: Any):
    """The pyproj CRS, its geodetic CRS and the Geod of its ellipsoid."""
    from pyproj import Geod

    from demtool.maps import to_pyproj_crs

    pcrs = to_pyproj_crs(crs)
    geodetic = pcrs.geodetic_crs or pcrs
    ellipsoid = geodetic.ellipsoid
    return pcrs, geodetic, Geod(a=ellipsoid.semi_major_metre, b=ellipsoid.semi_minor_metre)


def _points(transform: Any, centre: tuple[float, float], steps: np.ndarray) -> np.ndarray:
    """Map coordinates (N, 2) of the pixel ``centre`` moved by each of ``steps`` (N, 2)."""
    cols = centre[0] + steps[:, 0]
    rows = centre[1] + steps[:, 1]
    t = transform
    return np.column_stack([t.a * cols + t.b * rows + t.c, t.d * cols + t.e * rows + t.f])


def _east_north(points: np.ndarray, crs: Any) -> np.ndarray:
    """East/north metres (N-1, 2) from ``points[0]`` to each later point (map coords of
    ``crs``), along the geodesic on the CRS's ellipsoid."""
    from pyproj import Transformer

    pcrs, geodetic, geod = _geodetic(crs)
    to_lonlat = Transformer.from_crs(pcrs, geodetic, always_xy=True)
    lon, lat = to_lonlat.transform(points[:, 0], points[:, 1])
    lon, lat = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
    n = len(points) - 1
    azimuth, _, distance = geod.inv(np.full(n, lon[0]), np.full(n, lat[0]), lon[1:], lat[1:])
    azimuth = np.radians(np.asarray(azimuth, dtype=np.float64))
    distance = np.asarray(distance, dtype=np.float64)
    return np.column_stack([distance * np.sin(azimuth), distance * np.cos(azimuth)])


def _input_pixels(points: np.ndarray, crs: Any, grid: Any) -> np.ndarray:
    """Pixel offsets (N-1, 2) of ``grid`` from ``points[0]`` to each later point."""
    xy = points
    if crs is not None and grid.crs is not None:
        from pyproj import Transformer

        from demtool.maps import to_pyproj_crs

        source, target = to_pyproj_crs(crs), to_pyproj_crs(grid.crs)
        if not source.equals(target):
            transformer = Transformer.from_crs(source, target, always_xy=True)
            x, y = transformer.transform(points[:, 0], points[:, 1])
            xy = np.column_stack([x, y])
            if grid.is_geographic:  # one longitude branch for the differences
                xy[:, 0] = xy[0, 0] + (xy[:, 0] - xy[0, 0] + 180.0) % 360.0 - 180.0
    inverse = ~grid.transform
    cols = inverse.a * xy[:, 0] + inverse.b * xy[:, 1] + inverse.c
    rows = inverse.d * xy[:, 0] + inverse.e * xy[:, 1] + inverse.f
    return np.column_stack([cols[1:] - cols[0], rows[1:] - rows[0]])


def _propagate(jacobian: np.ndarray, sigma_x: float, sigma_y: float) -> tuple[float, float]:
    """One-sigma of a linear map's two outputs from independent input sigmas."""
    with np.errstate(invalid="ignore"):
        out = np.hypot(jacobian[:, 0] * sigma_x, jacobian[:, 1] * sigma_y)
    if not (np.isfinite(sigma_x) and np.isfinite(sigma_y)):
        out = np.where(np.isnan(out), np.inf, out)
    return float(out[0]), float(out[1])


def _finite(value: float) -> float:
    return float(value) if np.isfinite(value) else float("inf")


def shift_in_units(shift: Mapping[str, float], uncertainty: Mapping[str, float], grid: Any,
                   inputs: Sequence[tuple[str, Any]]) -> dict[str, Any]:
    """The comparison grid's shift in metres and in each input raster's own pixels.

    Parameters
    ----------
    shift, uncertainty : mapping
        ``dx_px``, ``dy_px`` (comparison-grid pixels, x right, y down) and ``dz``
        (metres): the shift added to the DEM and its one-sigma (inf: unconstrained).
    grid : demtool.compare.grids.Grid
        The comparison grid the shift is in (its CRS may be None: a frame without CRS).
    inputs : sequence of (name, Grid)
        The input rasters (e.g. ``("dem", …), ("reference", …)``); CRS None when
        ``grid``'s is None (rasters of one frame share their map coordinates).

    Returns
    -------
    dict
        ``shift_m``: ``{"east", "north", "up"}`` metres (``{"x", "y", "up"}`` along
        the raster's map axes when the grid has no CRS) with ``axes`` saying which;
        ``shift_uncertainty_m``: the same keys, one-sigma; ``shift_input_px``: per
        input name ``{"dx_px", "dy_px", "sigma_dx_px", "sigma_dy_px", "pixel_size",
        "pixel_units"}`` in that raster's own columns and rows.  All at the comparison
        grid's centre (a projection's distortion makes a constant grid shift vary across
        a large grid, e.g. on a polar stereographic map).
    """
    rows, cols = grid.shape
    centre = (cols / 2.0, rows / 2.0)
    dx, dy, dz = (float(shift[k]) for k in ("dx_px", "dy_px", "dz"))
    sx, sy, sz = (float(uncertainty[k]) for k in ("dx_px", "dy_px", "dz"))
    steps = np.array([[0.0, 0.0], [dx, dy], [1.0, 0.0], [0.0, 1.0]])
    points = _points(grid.transform, centre, steps)
    if grid.crs is not None:
        metres = _east_north(points, grid.crs)
        keys, axes = ("east", "north"), "east, north, up on the body at the grid's centre"
    else:
        metres = points[1:] - points[0]
        keys, axes = ("x", "y"), ("x, y along the raster's map axes (no CRS: not east and "
                                  "north), up")
    jacobian = metres[1:].T  # columns: one pixel step along x, along y
    sigma = _propagate(jacobian, sx, sy)
    shift_m = {keys[0]: float(metres[0, 0]), keys[1]: float(metres[0, 1]), "up": dz,
               "axes": axes}
    uncertainty_m = {keys[0]: sigma[0], keys[1]: sigma[1], "up": _finite(sz)}
    in_pixels: dict[str, Any] = {}
    for name, raster_grid in inputs:
        offsets = _input_pixels(points, grid.crs, raster_grid)
        sigma_px = _propagate(offsets[1:].T, sx, sy)
        units = "degrees" if raster_grid.is_geographic else \
            ("metres" if raster_grid.crs is not None else "map units")
        in_pixels[name] = {"dx_px": float(offsets[0, 0]), "dy_px": float(offsets[0, 1]),
                           "sigma_dx_px": sigma_px[0], "sigma_dy_px": sigma_px[1],
                           "pixel_size": list(raster_grid.spacing), "pixel_units": units}
    return {"shift_m": shift_m, "shift_uncertainty_m": uncertainty_m,
            "shift_input_px": in_pixels}
