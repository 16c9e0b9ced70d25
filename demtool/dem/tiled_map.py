"""``demtool dem``'s sensor-model routes in tiles: the job (the runner:
:mod:`demtool.dem.tiled_map_run`).

The untiled routes (:func:`demtool.dem.run_mapprojected.run_dem_mapprojected`, a
disparity between two orthoimages, and :func:`demtool.dem.run_sensors.run_dem_sensors`,
a disparity of a calibrated rectified pair) triangulate every disparity through the two
sensor models, drop rays that miss by more than the gap threshold, grid the points on
the body's map (the median of the points falling in each cell,
:func:`demtool.dem.sensors.dem_on_map`) and fill the stereo overlap.  In tiles, each
step resumable in the work folder:

1. **points** (tiles of the disparity grid, no margin): each disparity cell
   triangulated once; its longitude, latitude, height above the sphere, ray gap and
   left range cached in float64 (:func:`split64`; NaN where no point, or behind a
   camera); when the map's CRS is known up front (the orthoimages' or ``--t-srs``) its
   map x, y instead of longitude and latitude (and the range only where the GSD is
   estimated from it: :func:`point_fields`), so that the points are projected once,
   not again for the grid's extent and for each output tile they meet; the tiles a
   process computes it also keeps decoded (:func:`hold_points`, up to
   :data:`HELD_POINTS_MAX` points): its later passes take them from memory rather than
   decode the cache three times (the same numbers, :func:`tile_points`);
2. **statistics** (the runner, one cached tile at a time): exact medians
   (:func:`demtool.dem.tiled_map_run.streaming_median`) for the GSD, the gap threshold
   ``median + max(4 NMAD, 2 GSD)`` (:func:`demtool.dem.sensors.default_max_ray_gap`) and
   the overlap test's height; the map (the orthoimages' CRS, or one centred on the kept
   points' mean direction as :func:`demtool.maps.projections.choose_projection` does),
   the grid (the kept points' bounding box, :func:`demtool.maps.grids.snap_grid`) and
   each points tile's box in output cells;
3. **measured grid** (tiles of the output grid): each tile reads the points tiles whose
   box meets its core (so no margin has to be guessed from the height range) and takes
   the median per cell, the ray gaps likewise, and the stereo overlap of its cells
   (:func:`demtool.dem.sensors.overlap_mask`);
4. **coarse global fill, fine fills** as in :mod:`demtool.dem.tiled`
   (:func:`~demtool.dem.tiled_grids.prepare_fill`, :func:`~demtool.dem.tiled_grids.fill_core`):
   exact up to the solver's tolerance while the grid has at most
   :data:`demtool.dem.tiled.COARSE_MAX_CELLS` cells.

The per-cell median needs no neighbour and the statistics are exact, so the measured
grid equals the untiled one but for the order of floating-point sums (the map's
centre);
tests/dem/test_tiled_dem_sensors.py states the agreement achieved.
"""

from __future__ import annotations

import functools
import math
import os
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from demtool.dem.tiled import CELL_BYTES, PROCESS_BYTES
from demtool.dem.tiled_grids import fill_core, read_cached_window
from demtool.tiling import Tile, TileCache, Tiling, plan_tiles, read_window

POINT_BYTES = 400  # per disparity cell: raw coordinates, rays, points
#: the quantities a cached points tile may hold as :func:`split64` band pairs (x, y: map
#: coordinates, when the map's CRS is known up front)
POINT_FIELDS = ("lon", "lat", "height", "gap", "range_left", "x", "y")
#: those a points tile holds without map x, y (the order of its band pairs)
LONLAT_FIELDS = POINT_FIELDS[:5]
STEP_BANDS = {"measure": ("measured", "ray_gap", "overlap"),
              "fill": ("height", "interpolated", "ray_gap")}


def _stamp(path: str) -> tuple[str, int, int]:
    try:
        stat = os.stat(path)
    except OSError:  # not there: the reader says so (an error is never cached)
        return str(path), -1, -1
    return str(path), stat.st_mtime_ns, stat.st_size


def ortho(path: str, what: str):
    """:func:`demtool.dem.inputs.read_ortho`, once per process and file."""
    return _ortho(_stamp(path), what)


@functools.lru_cache(maxsize=4)
def _ortho(stamp: tuple[str, int, int], what: str):
    from demtool.dem.inputs import read_ortho

    return read_ortho(stamp[0], what=what)


def rectified_pair(path: str):
    """(left model, right model, RectifiedGeometry) of a calibrated rectify.npz, once per
    process and file."""
    return _rectified_pair(_stamp(path))


@functools.lru_cache(maxsize=2)
def _rectified_pair(stamp: tuple[str, int, int]):
    from demtool import io as dio
    from demtool.dem.inputs import geometry_from_rectification, models_from_rectification

    rectification = dio.read_npz(stamp[0], "rectification")
    left, right = models_from_rectification(rectification, stamp[0])
    return left, right, geometry_from_rectification(rectification, left, right)


def sphere_radius(model):
    """The surface heights are measured from for a model on a body: the reference
    sphere's radius (metres), or an RPC's ellipsoid (:attr:`demtool.maps.Body.surface`)."""
    from demtool.mapproject.core import sensor_body

    return sensor_body(model).surface


def split64(values: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """float64 values as two float32 bands, ``high + low`` (float32 tile caches keep
    them to ~1e-14 relative): (2, ...) float32, written into ``out`` when given (a
    (2, ...) float32 view of a tile being filled)."""
    values = np.asarray(values, dtype=np.float64)
    if out is None:
        out = np.empty((2, *values.shape), dtype=np.float32)
    out[0] = values
    out[1] = values - out[0].astype(np.float64)
    return out


def points_tiling(height: int, width: int, tile_size: int) -> Tiling:
    """The tiles of the points pass over a ``height × width`` disparity grid: rows of
    the whole width, as many as ``tile_size²`` cells make (at least), equally tall and
    that height rounded up to whole strips of the raw-coordinates lattice
    (:data:`demtool.mapproject.lattice.STRIP_ROWS` rows) once it is that tall, else
    :func:`demtool.tiling.plan_tiles`' squares where one row is more than ``tile_size²``
    cells.  The points of a cell do not depend on its tile but for the
    lattice's check points (within its 0.0001 px); whole-width rows cut the lattice
    into as few strips as the untiled route's, where squares added a strip (and its
    check points, each projected exactly) at every tile column.
    """
    from demtool.mapproject.lattice import STRIP_ROWS

    count = math.ceil(height * width / tile_size**2)
    rows = math.ceil(height / count)
    if rows >= STRIP_ROWS:
        rows = math.ceil(rows / STRIP_ROWS) * STRIP_ROWS
    if width > tile_size**2:
        return plan_tiles(height, width, tile_size, overlap=0)
    tiles = tuple(Tile(i, (r0, min(r0 + rows, height), 0, width),
                       (r0, min(r0 + rows, height), 0, width))
                  for i, r0 in enumerate(range(0, height, rows)))
    return Tiling(height, width, tile_size, (0, 0, 0, 0), tiles)


def load_points(cache: TileCache, tile: Tile) -> np.ndarray:
    """A cached points tile ``(B, h, w)`` float32, memory-mapped: only the bands
    :func:`stored_points` decodes are read (the statistics' passes read 3 of its bands,
    not all of them)."""
    return np.load(cache.path(tile), mmap_mode="r", allow_pickle=False)


#: most points a process keeps decoded from its points passes (4 to 5 float64 fields:
#: 256 to 320 MiB), as :data:`demtool.dem.tiled_map_run.MEDIAN_IN_MEMORY`
HELD_POINTS_MAX = 1 << 23
_HELD: dict[tuple[str, int], dict[str, np.ndarray]] = {}
_HELD_LOCK = threading.Lock()


def hold_points(folder: str, tile: Tile, values: np.ndarray,
                layout: tuple[str, ...]) -> None:
    """Keep a points tile just computed (``values`` as it is cached) decoded in this
    process, for the later passes (:func:`tile_points`): :func:`stored_points` of it, so
    the very numbers a pass decoding the cached file gets, decoded once, on the tile's
    thread.  Nothing is kept past :data:`HELD_POINTS_MAX` points in all."""
    decoded = dict(zip(layout, stored_points(values, layout, layout=layout), strict=True))
    count = decoded[layout[0]].size
    with _HELD_LOCK:
        held = sum(d[layout[0]].size for (f, _), d in _HELD.items() if f == folder)
        if held + count <= HELD_POINTS_MAX:
            _HELD[folder, tile.index] = decoded


def release_points(folder: str) -> None:
    """Forget the points tiles :func:`hold_points` kept of the cache ``folder``."""
    with _HELD_LOCK:
        for key in [k for k in _HELD if k[0] == folder]:
            del _HELD[key]


def tile_points(cache: TileCache, tile: Tile, fields: tuple[str, ...],
                chosen: np.ndarray | None = None,
                layout: tuple[str, ...] = LONLAT_FIELDS) -> tuple[np.ndarray, ...]:
    """:func:`stored_points` of a cached points tile: from what this process holds
    (:func:`hold_points`) when it computed the tile, else decoded from the cache."""
    held = _HELD.get((str(cache.folder), tile.index))
    if held is None:
        return stored_points(load_points(cache, tile), fields, chosen, layout)
    return tuple(held[name] if chosen is None else held[name][chosen] for name in fields)


def tile_point_count(cache: TileCache, tile: Tile,
                     layout: tuple[str, ...] = LONLAT_FIELDS) -> int:
    """:func:`point_count` of a cached points tile (held, or read from the cache)."""
    held = _HELD.get((str(cache.folder), tile.index))
    if held is None:
        return point_count(load_points(cache, tile), layout)
    return int(held[layout[0]].size)


def point_fields(map_xy: bool, range_left: bool = True) -> tuple[str, ...]:
    """The fields a points tile holds, in the order of its band pairs: with map x, y
    (``map_xy``: the map's CRS known up front) only what the later passes read (height,
    gap, x, y; ``range_left`` where the GSD is estimated from it), else
    :data:`LONLAT_FIELDS`."""
    if not map_xy:
        return LONLAT_FIELDS
    return ("height", "gap", *(("range_left",) if range_left else ()), "x", "y")


def point_count(values: np.ndarray, layout: tuple[str, ...] = LONLAT_FIELDS) -> int:
    """Points of a cached points tile (cells with a point)."""
    return int(np.isfinite(values[2 * layout.index("height")]).sum())


def stored_points(values: np.ndarray, fields: tuple[str, ...] = LONLAT_FIELDS,
                  chosen: np.ndarray | None = None,
                  layout: tuple[str, ...] = LONLAT_FIELDS) -> tuple[np.ndarray, ...]:
    """The ``fields`` (N,) float64 of a cached points tile's N points, whose band pairs
    (:func:`split64`) hold ``layout`` (:func:`point_fields`); only those decoded.
    ``chosen``: indices among those N points, only those decoded ((len(chosen),) each)."""
    ok = np.flatnonzero(np.isfinite(values[2 * layout.index("height")]).ravel())
    if chosen is not None:
        ok = ok[chosen]
    out = []
    for name in fields:
        i = layout.index(name)
        high = values[2 * i].reshape(-1)[ok]
        out.append(high.astype(np.float64) + values[2 * i + 1].reshape(-1)[ok])
    return tuple(out)


@dataclass(frozen=True)
class MapDemTileJob:
    """One tile of a tiled sensor-model route (picklable: paths and plain values).

    ``source`` is ``"mapprojected"`` (``left_path``, ``right_path``: the orthoimages) or
    ``"rectified"`` (``rectify_path``: a calibrated rectify.npz; ``disparity_bounds``:
    values outside are masked).  ``step`` is ``"points"`` (tiles of the disparity grid
    ``disparity_shape``), ``"measure"`` or ``"fill"`` (tiles of the output grid
    ``shape``, transform ``grid_transform``, CRS ``crs_wkt``); module docstring.
    """

    source: str
    disparity_path: str
    disparity_shape: tuple[int, int]
    tile_size: int
    left_path: str = ""
    right_path: str = ""
    rectify_path: str = ""
    disparity_bounds: tuple[float, float] = (-math.inf, math.inf)
    shape: tuple[int, int] = (0, 0)
    grid_transform: tuple[float, ...] = ()
    crs_wkt: str = ""
    points_crs_wkt: str = ""  # the CRS the points pass also maps x, y in ("": none)
    points: str = ""  # the points pass's cache folder
    boxes: tuple = ()  # per points tile: (row0, row1, col0, col1) output cells, or None
    max_gap: float = math.inf
    overlap_height: float = 0.0
    median_px: int = 0
    factor: int = 1
    step: str = "fill"
    work: str = ""
    ring: str = ""
    stage: str = "dem"
    # local --workers: tiles on threads (demtool.tiling.local_threads; audited: nogil
    # kernels, the cached models and orthoimages read-only)
    thread_safe: ClassVar[bool] = True
    # the outputs are written in tile order while the workers compute the later fill
    # tiles (demtool.tiling.jobs.run_tiled; the bytes of the end-of-run write): compute()
    # writes nothing through demtool.io
    stream_outputs: ClassVar[bool] = True
    bands: tuple[str, ...] = STEP_BANDS["fill"]
    row_shift: float = 0.0  # map rows sgm shifted the right ortho by (ROW_SHIFT_TAG)
    #: the points tiles' fields, in the order of their band pairs (:func:`point_fields`)
    point_layout: tuple[str, ...] = LONLAT_FIELDS

    def at_step(self, step: str, **changes: Any) -> MapDemTileJob:
        """This job for another step (its bands follow)."""
        job = replace(self, step=step, **changes)
        bands = (tuple(f"{name}_{part}" for name in job.point_layout
                       for part in ("high", "low")) if step == "points"
                 else STEP_BANDS[step])
        return replace(job, bands=bands)

    @property
    def cached_xy(self) -> bool:
        """Whether the points tiles hold map x, y in the output grid's CRS (the runner
        builds the grid in ``points_crs_wkt`` when it is set:
        :func:`demtool.dem.tiled_map_run._grid`)."""
        return bool(self.points_crs_wkt) and "x" in self.point_layout

    def sensors(self):
        """The (left, right) sensor models."""
        if self.source == "mapprojected":
            return (ortho(self.left_path, "left orthoimage").sensor,
                    ortho(self.right_path, "right orthoimage").sensor)
        return rectified_pair(self.rectify_path)[:2]

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        if self.step == "points":
            return self._points(tile)
        if self.step == "measure":
            return self._measure(tile)
        return self._fill(tile)

    # ------------------------------------------------------------------ step 1
    def _raw_ortho(self, disparity, r0, c0):
        """Raw (line, sample) of each side, the cells, and the rays
        (:class:`demtool.dem.ortho_rays.OrthoRays`) of the map-projected route."""
        from demtool.dem.ortho_rays import ortho_rays
        from demtool.mapproject.stereo import check_right_cells, disparity_cells
        from demtool.maps import to_pyproj_crs

        left = ortho(self.left_path, "left orthoimage")
        right = ortho(self.right_path, "right orthoimage")
        crs = to_pyproj_crs(left.info.crs)
        rows, l_cols, r_cols = disparity_cells(disparity)
        rows_g, l_g, r_g = rows + r0, l_cols + c0, r_cols + c0
        check_right_cells(self.disparity_path, self.right_path, l_g, r_g, right.info.width)
        r_rows = rows_g + self.row_shift  # sgm's shift of the right ortho, if any
        found = ortho_rays(left, right, crs, rows_g, l_g, r_rows, r_g)
        return (found.left[:2], found.right[:2], rows.astype(np.int64),
                l_cols.astype(np.int64), found)

    def _raw_rectified(self, disparity, r0, c0):
        """Raw (line, sample) of each side, and the cells, of the rectified route."""
        from demtool.rectify.calibrated import rect_to_pixels, scene_distance

        left, right, geometry = rectified_pair(self.rectify_path)
        low, high = self.disparity_bounds
        with np.errstate(invalid="ignore"):
            disparity[(disparity < low) | (disparity > high)] = np.nan
        rows, cols = np.nonzero(np.isfinite(disparity))
        x_left = (cols + c0).astype(np.float64)
        y = (rows + r0).astype(np.float64)
        x_right = x_left - disparity[rows, cols]
        return (rect_to_pixels(left, geometry, "left", x_left, y, scene_distance(left)),
                rect_to_pixels(right, geometry, "right", x_right, y, scene_distance(right)),
                rows, cols, None)

    def _points(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        from demtool.dem.sensors import triangulate_ground_rays, triangulate_sensors
        from demtool.maps.frames import xyz_to_lonlat_height

        r0, r1, c0, c1 = tile.core
        out = np.full((len(self.bands), r1 - r0, c1 - c0), np.nan, dtype=np.float32)
        disparity = read_window(self.disparity_path, tile.core, what="disparity")
        raw = self._raw_ortho if self.source == "mapprojected" else self._raw_rectified
        (l_line, l_sample), (r_line, r_sample), rows, cols, rays = raw(disparity, r0, c0)
        seen = (np.isfinite(l_line) & np.isfinite(l_sample) & np.isfinite(r_line)
                & np.isfinite(r_sample))
        if self.source == "rectified":  # the untiled route triangulates them all
            seen[:] = True
        info: dict[str, Any] = {"valid": int(rows.size), "seen": int(seen.sum()),
                                "behind": 0}
        if not seen.any():
            return out, info
        left, right = self.sensors()
        if rays is not None:  # the map-projected route: as untiled
            tri = triangulate_ground_rays(*rays.rays())
        else:
            tri = triangulate_sensors(left, right, l_line[seen], l_sample[seen],
                                      r_line[seen], r_sample[seen])
        finite = np.isfinite(tri.xyz).all(axis=1)
        front = finite & tri.in_front
        info["behind"] = int((finite & ~tri.in_front).sum())
        if not front.any():
            return out, info
        lon, lat, height = xyz_to_lonlat_height(tri.xyz[front], radii=sphere_radius(left))
        values = {"lon": lon, "lat": lat, "height": height, "gap": tri.gap[front],
                  "range_left": tri.range_left[front]}
        if self.points_crs_wkt:  # as demtool.dem.sensors.points_on_map: once per point
            from pyproj import CRS

            from demtool.maps.projections import lonlat_to_map

            values["x"], values["y"] = lonlat_to_map(CRS.from_wkt(self.points_crs_wkt),
                                                     lon, lat)
        cells = out.reshape(len(out), -1)  # a view
        at = rows[seen][front] * (c1 - c0) + cols[seen][front]
        dense = np.empty(cells.shape[1])
        for k, name in enumerate(self.point_layout):  # split64's pair, field by field
            dense.fill(np.nan)  # one scatter a field, then split64 on whole bands (the
            dense[at] = values[name]  # same two float32s as split64 of the points)
            split64(dense, out=cells[2 * k:2 * k + 2])
        if self.points:  # the later passes of this process take them decoded
            hold_points(self.points, tile, out, self.point_layout)
        return out, info

    # ------------------------------------------------------------------ step 3
    def _measure(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        from affine import Affine
        from pyproj import CRS

        from demtool.dem.grid import splat_median
        from demtool.dem.sensors import overlap_mask
        from demtool.mapproject.threads import available_threads, ordered_map
        from demtool.maps.grids import MapGrid
        from demtool.maps.projections import lonlat_to_map

        r0, r1, c0, c1 = tile.core
        h, w = r1 - r0, c1 - c0
        crs = CRS.from_wkt(self.crs_wkt)
        a, _, c, _, e, f = self.grid_transform[:6]
        ptiles = points_tiling(*self.disparity_shape, self.tile_size).tiles
        cache = TileCache(self.points)
        pixels, heights, gaps = [], [], []
        for ptile, box in zip(ptiles, self.boxes, strict=True):
            if box is None or box[0] >= r1 or box[1] <= r0 or box[2] >= c1 or box[3] <= c0:
                continue
            layout = self.point_layout
            if self.cached_xy:  # the cells first: only the points inside are decoded
                gap, x, y = tile_points(cache, ptile, ("gap", "x", "y"), layout=layout)
            else:
                lon, lat, gap = tile_points(cache, ptile, ("lon", "lat", "gap"),
                                            layout=layout)
            keep = gap <= self.max_gap
            every = bool(keep.all())  # as usual: the points used as they are, not copied
            if self.cached_xy:
                x, y = (x, y) if every else (x[keep], y[keep])
            else:
                x, y = lonlat_to_map(crs, *((lon, lat) if every else (lon[keep], lat[keep])))
            px = (np.asarray(x) - c) / a - 0.5  # as demtool.dem.sensors.dem_on_map
            py = (np.asarray(y) - f) / e - 0.5
            inside = (px > c0 - 0.5) & (px < c1 - 0.5) & (py > r0 - 0.5) & (py < r1 - 0.5)
            if not inside.any():
                continue
            pixels.append(np.column_stack([px[inside] - c0, py[inside] - r0]))
            # among the tile's points
            chosen = np.flatnonzero(inside) if every else np.flatnonzero(keep)[inside]
            heights.append(tile_points(cache, ptile, ("height",), chosen, layout)[0])
            gaps.append(gap[chosen])
        out = np.full((3, h, w), np.nan, dtype=np.float32)
        points = 0
        if pixels:
            p = np.concatenate(pixels)
            points = len(p)
            # the heights' and the gaps' medians at once where the tile has two threads
            # (nogil kernels), as demtool.dem.sensors.dem_on_map
            out[0], out[1] = (found[0] for found in ordered_map(
                lambda v: splat_median(p, v, (h, w)),
                (np.concatenate(heights), np.concatenate(gaps)),
                threads=min(2, available_threads())))
        grid = MapGrid(crs, Affine(*self.grid_transform[:6]) @ Affine.translation(c0, r0),
                       w, h)
        measured = np.isfinite(out[0])
        out[2] = overlap_mask(grid, *self.sensors(), self.overlap_height) | measured
        return out, {"points": points, "cells_measured": int(measured.sum())}

    # ------------------------------------------------------------------ step 4
    def _fill(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        core, measured = fill_core(tile, self.shape, self.tile_size, work=self.work,
                                   ring=self.ring, factor=self.factor,
                                   median_px=self.median_px)
        folder = Path(self.work) / "measured"
        raw = read_cached_window(folder, self.tile_size, self.shape, tile.core, band=0)
        error = read_cached_window(folder, self.tile_size, self.shape, tile.core, band=1)
        overlap = read_cached_window(folder, self.tile_size, self.shape, tile.core,
                                     band=2) > 0
        filled = overlap & ~measured
        dem = np.where(filled | (self.median_px > 1), core, raw)
        dem[~overlap] = np.nan
        mask = filled.astype(np.float64)
        mask[np.isnan(dem)] = np.nan
        info = TileCache(folder).info(tile)
        finite = dem[np.isfinite(dem)]
        return np.stack([dem, mask, error]).astype(np.float32), {
            "points": int(info.get("points", 0)), "cells_measured": int(measured.sum()),
            "cells_filled": int(filled.sum()), "cells_overlap": int(overlap.sum()),
            "height_min": float(finite.min()) if finite.size else math.inf,
            "height_max": float(finite.max()) if finite.size else -math.inf}

    def memory_bytes(self, tile: Tile) -> int:
        if self.step == "points":
            return PROCESS_BYTES + tile.core_shape[0] * tile.core_shape[1] * POINT_BYTES
        height, width = tile.outer_shape
        return PROCESS_BYTES + height * width * CELL_BYTES
