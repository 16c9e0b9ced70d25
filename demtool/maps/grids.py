"""Map grids on the body: a CRS, a north-up affine transform and a size.

A grid's transform is ``Affine(gsd, 0, x_west, 0, -gsd, y_north)``: row 0 is the
northern edge (in map y), cell (row r, column c) covers
[x_west + c·gsd, x_west + (c+1)·gsd] and its centre is at
(x_west + (c + 0.5)·gsd, y_north − (r + 0.5)·gsd) (GDAL's pixel-is-area convention).
Grids made here are snapped to whole pixels: their edges are multiples of the GSD
(ASP ``--tap``-like target-aligned pixels), so two grids of one GSD and CRS share
their pixel lattice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.maps.bodies import Body, to_pyproj_crs
from demtool.maps.frames import wrap_longitude, xyz_to_lonlat_height
from demtool.maps.projections import (
    POLAR_LATITUDE,
    choose_projection,
    crs_radius,
    footprint_center,
    lonlat_to_map,
    map_to_lonlat,
    map_to_xyz,
    projection_on,
)

__all__ = [
    "MapGrid",
    "degree_pixel_size",
    "grid_from_lonlat",
    "grid_from_xyz",
    "grid_lonlat",
    "grid_xyz",
    "height_above_sphere",
    "metric_grid_for",
    "snap_grid",
]


@dataclass(frozen=True)
class MapGrid:
    """A raster grid on a map projection.

    Attributes
    ----------
    crs : pyproj.CRS
        The projection (rasterio accepts it as is: ``write_raster(..., crs=grid.crs)``).
    transform : affine.Affine
        Pixel corner (column, row) → map (x, y), map units (metres when projected).
    width, height : int
        Columns and rows.
    """

    crs: Any
    transform: Any
    width: int
    height: int

    def __repr__(self) -> str:
        return (f"MapGrid(crs={self.crs.name!r}, transform={tuple(self.transform)[:6]}, "
                f"width={self.width}, height={self.height})")

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns)."""
        return (self.height, self.width)

    @property
    def gsd(self) -> tuple[float, float]:
        """Pixel size (x, y), map units, positive."""
        return abs(float(self.transform.a)), abs(float(self.transform.e))

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the grid's outer edges, map units."""
        x0, y0 = self.transform @ (0, 0)
        x1, y1 = self.transform @ (self.width, self.height)
        return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)

    def cell_centers(self) -> tuple[np.ndarray, np.ndarray]:
        """Map x, y of every cell centre, each (rows, columns) float64."""
        t = self.transform
        cols = np.arange(self.width, dtype=np.float64) + 0.5
        rows = np.arange(self.height, dtype=np.float64) + 0.5
        cc, rr = np.meshgrid(cols, rows)
        return t.a * cc + t.b * rr + t.c, t.d * cc + t.e * rr + t.f


def snap_grid(crs: Any, xmin: float, ymin: float, xmax: float, ymax: float, gsd: float
              ) -> MapGrid:
    """The smallest grid of pixel size ``gsd`` whose edges are multiples of ``gsd`` and
    that covers the box [xmin, xmax] × [ymin, ymax] (at least one pixel each way).

    Parameters
    ----------
    crs : CRS-like
    xmin, ymin, xmax, ymax : float, map units
    gsd : float, map units, > 0

    Returns
    -------
    MapGrid
    """
    from affine import Affine

    if not (np.isfinite(gsd) and gsd > 0):
        raise ValueError(f"gsd must be a positive number, got {gsd}")
    box = np.array([xmin, ymin, xmax, ymax], dtype=np.float64)
    if not np.isfinite(box).all() or xmax < xmin or ymax < ymin:
        raise ValueError(f"bad map box {box.tolist()}")
    # a tolerance of 1e-9 pixel keeps a box that already sits on the lattice unchanged
    x0 = math.floor(xmin / gsd + 1e-9) * gsd
    y1 = math.ceil(ymax / gsd - 1e-9) * gsd
    width = max(1, math.ceil((xmax - x0) / gsd - 1e-9))
    height = max(1, math.ceil((y1 - ymin) / gsd - 1e-9))
    return MapGrid(crs=to_pyproj_crs(crs), transform=Affine(gsd, 0.0, x0, 0.0, -gsd, y1),
                   width=int(width), height=int(height))


def _densify(lon: np.ndarray, lat: np.ndarray, closed: bool, steps: int = 16
             ) -> tuple[np.ndarray, np.ndarray]:
    """Points along each edge of a polygon (great-circle-ish in lon/lat, enough for
    projected bounds) so that curved edges in the map are covered."""
    if lon.size < 2 or not closed:
        return lon, lat
    center = lon[0]
    lon = wrap_longitude(lon, center)
    lon_next = np.roll(lon, -1)
    lat_next = np.roll(lat, -1)
    t = np.linspace(0.0, 1.0, steps, endpoint=False)[:, None]
    return (lon + t * (lon_next - lon)).ravel(), (lat + t * (lat_next - lat)).ravel()


def grid_from_lonlat(body: Body, lon_deg: np.ndarray, lat_deg: np.ndarray, gsd_m: float, *,
                     projection: str = "auto", crs: Any = None, polygon: bool = True
                     ) -> MapGrid:
    """A map grid covering a footprint given in longitude and latitude.

    Parameters
    ----------
    body : Body
    lon_deg, lat_deg : (N,) float, degrees
        Footprint polygon vertices (``polygon=True``: its edges are densified) or
        ground points, planetocentric, east-positive.
    gsd_m : float
        Pixel size, metres (map units of the projection).
    projection : {"auto", "equirectangular", "polar-stereographic"}
        Used when ``crs`` is None (see :mod:`demtool.maps.projections`).
    crs : CRS-like, optional
        A given projected CRS instead (e.g. another DEM's).
    polygon : bool
        Whether the points are a polygon's vertices in order.

    Returns
    -------
    MapGrid
        Snapped to whole pixels (:func:`snap_grid`).
    """
    lon = np.asarray(lon_deg, dtype=np.float64).ravel()
    lat = np.asarray(lat_deg, dtype=np.float64).ravel()
    keep = np.isfinite(lon) & np.isfinite(lat)
    lon, lat = lon[keep], lat[keep]
    if lon.size == 0:
        raise ValueError("footprint has no finite point")
    if crs is None:
        crs = choose_projection(body, lon, lat, projection)
    lon, lat = _densify(lon, lat, polygon)
    x, y = lonlat_to_map(crs, lon, lat)
    good = np.isfinite(x) & np.isfinite(y)
    if not good.any():
        raise ValueError("footprint cannot be projected in the chosen CRS")
    return snap_grid(crs, x[good].min(), y[good].min(), x[good].max(), y[good].max(), gsd_m)


def grid_from_xyz(body: Body, xyz: np.ndarray, gsd_m: float, *, projection: str = "auto",
                  crs: Any = None) -> MapGrid:
    """A map grid covering body-fixed points (e.g. triangulated ground points).

    Parameters
    ----------
    body : Body
    xyz : (..., 3) float, metres, body-fixed (NaN rows ignored)
    gsd_m, projection, crs
        As in :func:`grid_from_lonlat`.

    Returns
    -------
    MapGrid
    """
    lon, lat, _ = xyz_to_lonlat_height(np.asarray(xyz, dtype=np.float64).reshape(-1, 3),
                                       radii=body.surface)
    return grid_from_lonlat(body, lon, lat, gsd_m, projection=projection, crs=crs,
                            polygon=False)


def grid_lonlat(grid: MapGrid) -> tuple[np.ndarray, np.ndarray]:
    """Longitude and latitude (degrees) of every cell centre, each (rows, columns)."""
    x, y = grid.cell_centers()
    return map_to_lonlat(grid.crs, x, y)


def grid_xyz(grid: MapGrid, heights: np.ndarray | float = 0.0) -> np.ndarray:
    """Body-fixed XYZ of every cell centre on the grid's sphere raised by ``heights``.

    Parameters
    ----------
    grid : MapGrid
        On a sphere (demtool's maps).
    heights : (rows, columns) float or float, metres above the sphere
        NaN heights give NaN points.

    Returns
    -------
    (rows, columns, 3) float64, metres
    """
    x, y = grid.cell_centers()
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim and h.shape != grid.shape:
        raise ValueError(f"heights have shape {h.shape}, grid is {grid.shape}")
    return map_to_xyz(grid.crs, x, y, h)


def holds_radii(values: np.ndarray, radius: float) -> bool:
    """Whether a DEM's values (metres) are radii rather than heights: ISIS shape models
    such as LOLA's ``ldem_*.cub`` and MOLA's store the distance from the body's centre,
    and their median exceeds half the body's radius, which no height does.

    Parameters
    ----------
    values : array of metres (NaN ignored)
    radius : float, the body's reference sphere, metres
    """
    finite = np.asarray(values)[np.isfinite(values)]
    return bool(finite.size) and abs(float(np.median(finite))) > 0.5 * radius


def height_above_sphere(xyz: np.ndarray, radius: float) -> np.ndarray:
    """Height of body-fixed points above a sphere centred on the body, metres.

    Parameters
    ----------
    xyz : (..., 3) float, metres
    radius : float, metres (``body.radius`` for demtool's maps)

    Returns
    -------
    (...) float64: ``|xyz| − radius``
    """
    return np.linalg.norm(np.asarray(xyz, dtype=np.float64), axis=-1) - float(radius)


def degree_pixel_size(transform: Any, center_lat: float, radius: float
                      ) -> tuple[float, float]:
    """Ground size (x, y) in metres of a pixel of a geographic (degree) grid.

    Along a parallel at ``center_lat`` a degree of longitude is R·cos φ·π/180 m; along a
    meridian a degree of latitude is R·π/180 m.

    Parameters
    ----------
    transform : affine.Affine, degrees
    center_lat : float, degrees
    radius : float, metres

    Returns
    -------
    (float, float), metres
    """
    per_degree = float(radius) * math.pi / 180.0
    dlon = math.hypot(transform.a, transform.d)
    dlat = math.hypot(transform.b, transform.e)
    return (dlon * per_degree * math.cos(math.radians(center_lat)), dlat * per_degree)


def metric_grid_for(crs: Any, transform: Any, shape: tuple[int, int], *,
                    projection: str = "auto") -> MapGrid:
    """A metric grid over the footprint of a geographic (degree) grid.

    The projection (``auto``: polar stereographic poleward of ±70°, equirectangular
    centred on the footprint otherwise) is built on the grid's own geodetic CRS, so a
    reprojection onto it changes no datum; its pixel size is the geometric mean of the
    degree pixel's ground size at the footprint's centre (:func:`degree_pixel_size`
    with the CRS's semi-major axis), so the pixel count stays about the same.

    Parameters
    ----------
    crs : CRS-like, geographic
    transform : affine.Affine, degrees
    shape : (rows, columns)
    projection : {"auto", "equirectangular", "polar-stereographic"}

    Returns
    -------
    MapGrid
    """
    pcrs = to_pyproj_crs(crs)
    if not pcrs.is_geographic:
        raise ValueError(f"CRS {pcrs.name!r} is not geographic")
    rows, cols = shape
    edge_c = np.concatenate([np.linspace(0, cols, 17), np.full(17, cols),
                             np.linspace(cols, 0, 17), np.zeros(17)])
    edge_r = np.concatenate([np.zeros(17), np.linspace(0, rows, 17), np.full(17, rows),
                             np.linspace(rows, 0, 17)])
    t = transform
    lon = t.a * edge_c + t.b * edge_r + t.c
    lat = np.clip(t.d * edge_c + t.e * edge_r + t.f, -90.0, 90.0)
    center_lon, center_lat = footprint_center(lon, lat)
    kind = projection
    if kind == "auto":
        kind = "polar-stereographic" if abs(center_lat) >= POLAR_LATITUDE else "equirectangular"
    projected = projection_on(pcrs, kind, center_lon, center_lat)
    try:
        radius = crs_radius(pcrs)
    except ValueError:
        radius = (pcrs.geodetic_crs or pcrs).ellipsoid.semi_major_metre
    sx, sy = degree_pixel_size(transform, center_lat, radius)
    gsd = math.sqrt(sx * sy) if sx > 0 else sy
    x, y = lonlat_to_map(projected, lon, lat)
    good = np.isfinite(x) & np.isfinite(y)
    return snap_grid(projected, x[good].min(), y[good].min(), x[good].max(), y[good].max(),
                     gsd)
