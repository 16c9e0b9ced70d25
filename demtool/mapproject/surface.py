"""What map-projected products share with the stages that read them: the tags an
orthoimage carries, the projection surface (a DEM or a constant height) read for a
sensor, the body check, and a raw image resampled onto a DEM's grid.

Used by the ``mapproject`` runner and its tiled job, by ``dem --mapprojected`` and by
``refine`` on the map (:mod:`demtool.refine.run_map`).
"""

from __future__ import annotations

import math
import os
from typing import Any, NamedTuple

import numpy as np

#: tags every orthoimage carries so later stages can undo the projection
SENSOR_TAG = "mapproject_sensor"
SURFACE_TAG = "mapproject_surface"
DEM_TAG = "mapproject_dem"
HEIGHT_TAG = "mapproject_height_m"


#: Most DEM cells :meth:`DemSurface.holding` keeps in memory (float32: 64 MiB); a larger
#: window stays on disk, read tile by tile
HOLD_MAX_CELLS = 16 * 2**20
#: Cells added on each side of the window :meth:`DemSurface.holding` keeps (the map
#: grid is the DEM's lattice over the footprint snapped outward, and each window read
#: reaches 1–3 cells past its points)
HOLD_MARGIN = 8
#: Fewest DEM rows per thread of :meth:`DemSurface.holding`'s read (a part opens the file)
HOLD_MIN_ROWS_PER_PART = 256
#: Heights at scattered points (the image's outer edge) on a DEM not held in memory: when
#: the window spanning the points has more cells than this, and at most
#: :data:`SPARSE_MAX_POINTS` points, each point's own 4 × 4 cells are read instead of the
#: window (a DEM over :data:`HOLD_MAX_CELLS` would otherwise be read whole, on one core,
#: for a few dozen heights)
SPARSE_MIN_CELLS = 2**20
SPARSE_MAX_POINTS = 4096


class DemSurface(NamedTuple):
    """A DEM read in windows: its :class:`demtool.io.RasterInfo` and the offset (metres)
    from its own sphere's heights to heights above the body's reference sphere.

    ``held``: a window ``(row0, row1, col0, col1)`` of the DEM and its values
    (:func:`demtool.io.read_window`'s float32), kept in memory by :meth:`holding`;
    windows inside it are sliced from it instead of read again (the same values)."""

    info: Any
    offset_m: float
    geographic: bool
    held: tuple[tuple[int, int, int, int], np.ndarray] | None = None

    def map_xy(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates in the DEM's own CRS of lon/lat (degrees)."""
        from demtool.maps import lonlat_to_map, wrap_longitude

        if self.geographic:
            t = self.info.transform
            center = t.c + t.a * 0.5 * self.info.width
            return wrap_longitude(lon, center), np.asarray(lat, dtype=np.float64)
        return lonlat_to_map(self.info.crs, lon, lat)

    def heights_lonlat(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Heights (metres above the body's sphere) at lon/lat (degrees), bilinear."""
        return self.heights_xy(*self.map_xy(lon, lat))

    def _positions(self, x: np.ndarray, y: np.ndarray):
        """Fractional (row, col) of map x, y and the window of cells their bilinear
        interpolation reads (None: no finite position on the DEM)."""
        inv = ~self.info.transform
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        col = inv.a * x + inv.b * y + inv.c - 0.5
        row = inv.d * x + inv.e * y + inv.f - 0.5
        good = np.isfinite(col) & np.isfinite(row)
        if not good.any():
            return row, col, None
        window = self._cells_round(row[good].min(), row[good].max(), col[good].min(),
                                   col[good].max())
        return row, col, window

    def _cells_round(self, row_min: float, row_max: float, col_min: float,
                     col_max: float) -> tuple[int, int, int, int] | None:
        """The DEM's cells that bilinear interpolation reads for fractional positions in
        ``[row_min, row_max] × [col_min, col_max]`` (a cell's margin each side, clipped to
        the DEM), as ``(row0, row1, col0, col1)``; None when that is empty (off the DEM).
        One rule for the window spanning many points and for one point's own cells, so
        both give the same heights."""
        r0 = max(int(math.floor(row_min)) - 1, 0)
        r1 = min(int(math.floor(row_max)) + 3, self.info.height)
        c0 = max(int(math.floor(col_min)) - 1, 0)
        c1 = min(int(math.floor(col_max)) + 3, self.info.width)
        if r1 <= r0 or c1 <= c0:
            return None
        return r0, r1, c0, c1

    def heights_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Heights at map coordinates of the DEM's own CRS (NaN off the DEM)."""
        from demtool.mapproject.core import bilinear_heights

        row, col, window = self._positions(x, y)
        if window is None:
            return np.full(np.shape(col), np.nan)
        if self._sparse(window, row.size):
            return self._heights_at_points(row, col) + self.offset_m
        r0, _, c0, _ = window
        out = bilinear_heights(self._window(window), row - r0, col - c0)
        return out + self.offset_m

    def _sparse(self, window: tuple[int, int, int, int], points: int) -> bool:
        """Whether a few points spread over a large window not held in memory are read
        point by point (:data:`SPARSE_MIN_CELLS`)."""
        if points > SPARSE_MAX_POINTS:
            return False
        if self._held_part(window) is not None:
            return False
        r0, r1, c0, c1 = window
        return (r1 - r0) * (c1 - c0) > SPARSE_MIN_CELLS

    def _heights_at_points(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """:func:`bilinear_heights` at fractional DEM positions, each from its own cells
        (the window :meth:`_positions` gives one point, read with the others'
        (:func:`demtool.io.read_windows`): the cells and the clipping at the DEM's edges
        are those of the window spanning every point, so the heights are the same)."""
        from demtool import io as dio
        from demtool.mapproject.core import bilinear_heights

        out = np.full(row.shape, np.nan)
        flat_row, flat_col, flat_out = row.reshape(-1), col.reshape(-1), out.reshape(-1)
        chosen, windows = [], []
        for index in np.flatnonzero(np.isfinite(flat_row) & np.isfinite(flat_col)):
            r, c = flat_row[index], flat_col[index]
            window = self._cells_round(r, r, c, c)
            if window is not None:
                chosen.append(index)
                windows.append(window)
        for index, window, values in zip(chosen, windows,
                                         dio.read_windows(self.info.path, windows, what="DEM"),
                                         strict=True):
            flat_out[index] = bilinear_heights(values, flat_row[index:index + 1] - window[0],
                                               flat_col[index:index + 1] - window[2])[0]
        return out

    def _held_part(self, window: tuple[int, int, int, int]) -> np.ndarray | None:
        """The DEM's values in ``window`` sliced from the held window (None when no
        window is held or ``window`` reaches outside it)."""
        if self.held is None:
            return None
        r0, r1, c0, c1 = window
        (h0, h1, g0, g1), values = self.held
        if h0 <= r0 and r1 <= h1 and g0 <= c0 and c1 <= g1:
            return values[r0 - h0:r1 - h0, c0 - g0:c1 - g0]
        return None

    def _window(self, window: tuple[int, int, int, int]) -> np.ndarray:
        """The DEM's values in ``window``: sliced from the held window when inside it."""
        held = self._held_part(window)
        if held is not None:
            return held
        from demtool import io as dio

        return dio.read_window(self.info.path, window, what="DEM")

    def holding(self, lon: np.ndarray, lat: np.ndarray, *, margin: int = HOLD_MARGIN,
                max_cells: int = HOLD_MAX_CELLS) -> DemSurface:
        """This surface with the DEM's window under the points (lon/lat, degrees), widened
        by ``margin`` cells, held in memory (read once; itself when that window has more
        than ``max_cells`` cells or no point falls on the DEM)."""
        _, _, window = self._positions(*self.map_xy(lon, lat))
        if window is None:
            return self
        r0, r1, c0, c1 = window
        window = (max(r0 - margin, 0), min(r1 + margin, self.info.height),
                  max(c0 - margin, 0), min(c1 + margin, self.info.width))
        if (window[1] - window[0]) * (window[3] - window[2]) > max_cells:
            return self
        return self._replace(held=(window, self._read_rows_on_threads(window)))

    def _read_rows_on_threads(self, window: tuple[int, int, int, int]) -> np.ndarray:
        """The DEM's values in ``window`` (float32, NaN nodata), its rows read in parts
        on this thread and its helpers (:func:`demtool.tiling.rows.on_row_parts`): GDAL's
        read and decompression and the conversion to float32 release the GIL, and this
        read is on the critical path before the first map tile.  Each part is
        :func:`demtool.io.read_window` of its rows, elementwise: the values equal one
        read of the whole window."""
        from demtool import io as dio
        from demtool.tiling.rows import on_row_parts

        r0, r1, c0, c1 = window
        out = np.empty((r1 - r0, c1 - c0), dtype=np.float32)

        def read(start: int, stop: int) -> None:
            out[start:stop] = dio.read_window(self.info.path, (r0 + start, r0 + stop, c0, c1),
                                              what="DEM")

        on_row_parts(read, r1 - r0, min_rows=HOLD_MIN_ROWS_PER_PART)
        return out


def require_same_body(path: str | os.PathLike, crs: Any, body: Any,
                      sensor_path: str | os.PathLike, what: str) -> None:
    """InputError naming both files when the raster at ``path`` (CRS ``crs``) is on
    another body than the sensor model's ``body``."""
    from demtool.errors import InputError
    from demtool.maps import body_from_crs, same_body

    raster_body = body_from_crs(crs)
    if not same_body(raster_body, body):
        raise InputError(f"{path}: is {what} of {raster_body.name} but the sensor model "
                         f"{sensor_path} sees {body.name}")


def read_dem_surface(dem_path, sensor_path, body) -> DemSurface:
    """The DEM at ``dem_path`` as a :class:`DemSurface` (checked: a map of the sensor's
    body, on a sphere).  Heights above the map's sphere, or radii (an ISIS shape model,
    told by :func:`demtool.maps.holds_radii` on a decimated read): both become heights
    above the body's reference sphere."""
    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.maps import crs_radius, to_pyproj_crs

    info = dio.raster_info(dem_path, what="DEM")
    if info.crs is None:
        raise InputError(f"{dem_path}: DEM has no CRS; a DEM on the body's map (a "
                         "planetary CRS) is needed")
    crs = to_pyproj_crs(info.crs)
    require_same_body(dem_path, crs, body, sensor_path, "a DEM")
    if body.height_reference == "ellipsoid":  # an RPC's heights: above its ellipsoid
        return DemSurface(info=info, offset_m=_ellipsoid_offset(dem_path, crs, body),
                          geographic=crs.is_geographic)
    try:
        radius = crs_radius(crs)
    except ValueError:
        raise InputError(f"{dem_path}: DEM is on an ellipsoid; demtool's map heights are above "
                         "the body's reference sphere (reproject it onto the sphere)") from None
    offset_m = radius - body.radius
    from demtool.maps import holds_radii

    if holds_radii(dio.read_decimated(dem_path, what="DEM"), body.radius):
        # an ISIS shape model (LOLA ldem_*, MOLA, demprep output) stores radii
        offset_m = -float(body.radius)
        from demtool.logs import get_logger

        get_logger("demtool.mapproject").info("DEM %s holds radii (ISIS shape model): heights "
                                              "are the radii minus %.1f m", dem_path,
                                              body.radius)
    return DemSurface(info=info, offset_m=offset_m, geographic=crs.is_geographic)


def _ellipsoid_offset(dem_path, crs, body) -> float:
    """0 when a DEM's heights are above the body's ellipsoid (the one an RPC's heights
    are above: a DEM on WGS 84, e.g. UTM or EPSG:4326, for an Earth RPC); InputError
    for a DEM on a sphere or another ellipsoid, whose heights differ by up to the
    flattening (21 km on Earth)."""
    from demtool.errors import InputError
    from demtool.maps import GeodeticEllipsoid, crs_surface

    vertical = [c for c in (crs.sub_crs_list if crs.is_compound else []) if c.is_vertical]
    if vertical:  # SRTM-like heights above a geoid: not the RPC's heights
        raise InputError(f"{dem_path}: DEM heights are above {vertical[0].name!r}; the "
                         "sensor's heights are above the ellipsoid (convert the DEM to "
                         "ellipsoidal heights, e.g. gdalwarp with a +geoidgrids shift)")
    surface = crs_surface(crs)
    if isinstance(surface, GeodeticEllipsoid) and math.isclose(
            surface.a, body.a, rel_tol=1e-9) and math.isclose(surface.c, body.c, rel_tol=1e-9):
        return 0.0
    described = (f"a sphere of radius {surface:.10g} m" if not isinstance(
        surface, GeodeticEllipsoid) else f"the ellipsoid a={surface.a:.10g}, c={surface.c:.10g} m")
    raise InputError(f"{dem_path}: DEM heights are above {described}; the sensor's heights are "
                     f"above the ellipsoid a={body.a:.10g}, c={body.c:.10g} m (reproject the "
                     "DEM onto it, e.g. EPSG:4326 or UTM on WGS 84)")


def orthoimage_on_grid(image_path: str | os.PathLike, sensor, dem) -> np.ndarray:
    """An image map-projected (in memory) onto a DEM's grid at the DEM's heights.

    Parameters
    ----------
    image_path : path-like
        The raw image (read in windows).
    sensor : SensorModel
        Its model; the image must have the model's size.
    dem : demtool.io.Raster
        Heights above the body's reference sphere on a projected map grid.

    Returns
    -------
    (H, W) float32 on the DEM's grid, NaN where not seen.
    """
    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.mapproject.core import image_coordinates, image_window, resample_tile, tile_windows
    from demtool.mapproject.params import MapprojectParams

    info = dio.raster_info(image_path, what="image")
    if (info.height, info.width) != sensor.image_size:
        raise InputError(f"{image_path}: image is {info.width} x {info.height} pixels but its "
                         f"sensor model describes {sensor.samples} x {sensor.lines}")
    defaults = MapprojectParams()
    out = np.full(dem.data.shape, np.nan, dtype=np.float32)
    for window in tile_windows(dem.data.shape, defaults.tile_size):
        r0, r1, c0, c1 = window
        coords = image_coordinates(sensor, dem.crs, dem.transform, window,
                                   dem.data[r0:r1, c0:c1], step=defaults.step,
                                   tolerance=defaults.tolerance)
        span = image_window(coords.line, coords.sample, sensor.lines, sensor.samples)
        if span is None:
            continue
        pixels = dio.read_window(image_path, span, what="image")
        out[r0:r1, c0:c1] = resample_tile(pixels, (span[0], span[2]), coords.line,
                                          coords.sample, sensor.lines, sensor.samples)
    return out
