"""``demtool dem --disparity D --mapprojected LEFT RIGHT`` in tiles (the pushbroom route).

The untiled route (:func:`demtool.runs.dem_mapprojected.run_dem_mapprojected`)
triangulates every disparity through the orthoimages' sensor models, drops rays that
miss by more than the gap threshold, grids the points on the body's map (the median of
the points falling in each cell, :func:`demtool.dem.sensors.dem_on_map`) and fills the
stereo overlap.  Here, each step resumable in the work folder:

1. **points** (tiles of the disparity grid, no margin): each disparity cell
   triangulated once; its map position (offset from the cell's centre, metres), height
   above the sphere and ray gap cached as a tile (NaN where unseen or behind a camera);
2. **statistics** (this process, one cached tile at a time): the gap threshold
   ``median + max(4 NMAD, 2 GSD)`` (:func:`demtool.dem.sensors.default_max_ray_gap`)
   from histograms of the gaps and of their deviations, the map bounding box of the kept
   points (the output grid, :func:`demtool.maps.grids.snap_grid`), each disparity
   tile's box in output cells, and the kept heights' median (the overlap test's height);
3. **measured grid** (tiles of the output grid): each tile reads the disparity tiles
   whose box meets its core and takes the median per cell, the ray gaps likewise, and the
   stereo overlap of its cells (:func:`demtool.dem.sensors.overlap_mask`);
4. **coarse global fill, fine fills** as in :mod:`demtool.tiled.dem`
   (:func:`~demtool.tiled.dem.prepare_fill`, :func:`~demtool.tiled.dem.fill_core`):
   exact up to the solver's tolerance when the grid has at most
   :data:`demtool.tiled.dem.COARSE_MAX_CELLS` cells.

The per-cell median needs no neighbour, so the measured grid equals the untiled one up
to the statistics' histograms: the threshold (:data:`GAP_BINS_PER_DECADE` log bins,
0.023 %) and the overlap height (:data:`HEIGHT_BIN_M` bins).  tests/dem/
test_tiled_dem_sensors.py states the agreement achieved.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from demtool.tiled.dem import (
    CELL_BYTES,
    PROCESS_BYTES,
    coarse_factor,
    default_overlap,
    fill_core,
    prepare_fill,
)
from demtool.tiled.dem_grids import histogram_median, log_histogram, read_cached_window
from demtool.tiling import Tile, TileCache, plan_tiles, read_window

GAP_BINS_PER_DECADE = 10_000  # histograms of the ray gaps and their deviations
HEIGHT_BIN_M = 0.01  # histogram of the kept heights (the overlap test's median height)
POINT_BYTES = 400  # per disparity cell: raw coordinates, rays, points
STEP_BANDS = {"points": ("dx", "dy", "height", "gap"),
              "measure": ("measured", "ray_gap", "overlap"),
              "fill": ("height", "interpolated", "ray_gap")}


@functools.lru_cache(maxsize=4)
def _ortho(path: str, what: str):
    from demtool.runs.dem_mapprojected import read_ortho

    return read_ortho(path, what=what)


@dataclass(frozen=True)
class MapDemTileJob:
    """One tile of the tiled map-projected route (picklable: paths and plain values).

    ``step`` is ``"points"`` (tiles of the disparity grid ``disparity_shape``),
    ``"measure"`` or ``"fill"`` (tiles of the output grid ``shape``, transform
    ``grid_transform`` in the orthoimages' CRS); module docstring.
    """

    disparity_path: str
    left_path: str
    right_path: str
    disparity_shape: tuple[int, int]
    tile_size: int
    shape: tuple[int, int] = (0, 0)
    grid_transform: tuple[float, ...] = ()
    points: str = ""  # the points pass's cache folder
    boxes: tuple = ()  # per disparity tile: (row0, row1, col0, col1) output cells or None
    max_gap: float = math.inf
    overlap_height: float = 0.0
    median_px: int = 0
    factor: int = 1
    step: str = "fill"
    work: str = ""
    ring: str = ""
    stage: str = "dem"
    bands: tuple[str, ...] = STEP_BANDS["fill"]

    def at_step(self, step: str, **changes: Any) -> MapDemTileJob:
        """This job for another step (its bands follow)."""
        return replace(self, step=step, bands=STEP_BANDS[step], **changes)

    def orthos(self):
        return (_ortho(self.left_path, "left orthoimage"),
                _ortho(self.right_path, "right orthoimage"))

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        if self.step == "points":
            return self._points(tile)
        if self.step == "measure":
            return self._measure(tile)
        return self._fill(tile)

    # ------------------------------------------------------------------ step 1
    def _points(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        from demtool.dem.sensors import triangulate_sensors
        from demtool.maps import body_from_radii, to_pyproj_crs
        from demtool.maps.frames import xyz_to_lonlat_height
        from demtool.maps.projections import lonlat_to_map
        from demtool.mapstereo import disparity_cells, map_cells_xy, raw_coordinates

        left, right = self.orthos()
        li = left.info
        crs = to_pyproj_crs(li.crs)
        r0, r1, c0, c1 = tile.core
        out = np.full((4, r1 - r0, c1 - c0), np.nan, dtype=np.float32)
        disparity = read_window(self.disparity_path, tile.core, what="disparity")
        rows, l_cols, r_cols = disparity_cells(disparity)
        info = {"valid": int(rows.size), "seen": 0, "behind": 0}
        if rows.size == 0:
            return out, info
        rows_g, l_g, r_g = rows + r0, l_cols + c0, r_cols + c0
        l_h = left.heights(*map_cells_xy(li.transform, rows_g, l_g))
        r_h = right.heights(*map_cells_xy(right.info.transform, rows_g, r_g))
        l_line, l_sample = raw_coordinates(left.sensor, crs, li.transform, rows_g, l_g, l_h)
        r_line, r_sample = raw_coordinates(right.sensor, crs, right.info.transform, rows_g,
                                           r_g, r_h)
        seen = (np.isfinite(l_line) & np.isfinite(l_sample) & np.isfinite(r_line)
                & np.isfinite(r_sample))
        info["seen"] = int(seen.sum())
        if not seen.any():
            return out, info
        tri = triangulate_sensors(left.sensor, right.sensor, l_line[seen], l_sample[seen],
                                  r_line[seen], r_sample[seen])
        finite = np.isfinite(tri.xyz).all(axis=1)
        front = finite & tri.in_front
        info["behind"] = int((finite & ~tri.in_front).sum())
        a, b = left.sensor.radii
        radius = body_from_radii(a, a, b).radius
        lon, lat, height = xyz_to_lonlat_height(tri.xyz[front], radii=radius)
        x, y = lonlat_to_map(crs, lon, lat)
        cell_rows = rows[seen][front].astype(np.int64)
        cell_cols = l_cols[seen][front].astype(np.int64)
        x0, y0 = map_cells_xy(li.transform, cell_rows + r0, cell_cols + c0)
        values = np.stack([np.asarray(x) - x0, np.asarray(y) - y0, height, tri.gap[front]])
        out[:, cell_rows, cell_cols] = values
        return out, info

    # ------------------------------------------------------------------ step 3
    def _cells(self, values: np.ndarray, dtile: Tile) -> tuple[np.ndarray, np.ndarray]:
        """Output-grid pixel positions (x = col − 0.5, y = row − 0.5 as in
        :func:`~demtool.dem.sensors.dem_on_map`) of a cached points tile's cells."""
        from demtool.mapstereo import map_cells_xy

        left, _ = self.orthos()
        r0, r1, c0, c1 = dtile.core
        rows, cols = np.mgrid[r0:r1, c0:c1]
        x0, y0 = map_cells_xy(left.info.transform, rows.ravel(), cols.ravel())
        a, _, c, _, e, f = self.grid_transform[:6]
        x = x0 + values[0].ravel().astype(np.float64)
        y = y0 + values[1].ravel().astype(np.float64)
        return (x - c) / a - 0.5, (y - f) / e - 0.5

    def _measure(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        from affine import Affine

        from demtool.dem.grid import splat_median
        from demtool.dem.sensors import overlap_mask
        from demtool.maps import to_pyproj_crs
        from demtool.maps.grids import MapGrid

        r0, r1, c0, c1 = tile.core
        h, w = r1 - r0, c1 - c0
        dtiles = plan_tiles(*self.disparity_shape, self.tile_size, overlap=0).tiles
        cache = TileCache(self.points)
        pixels, heights, gaps = [], [], []
        for dtile, box in zip(dtiles, self.boxes, strict=True):
            if box is None or box[0] >= r1 or box[1] <= r0 or box[2] >= c1 or box[3] <= c0:
                continue
            values = cache.load(dtile)
            px, py = self._cells(values, dtile)
            height = values[2].ravel().astype(np.float64)
            gap = values[3].ravel().astype(np.float64)
            keep = (np.isfinite(height) & (gap <= self.max_gap) & (px > c0 - 0.5)
                    & (px < c1 - 0.5) & (py > r0 - 0.5) & (py < r1 - 0.5))
            pixels.append(np.column_stack([px[keep] - c0, py[keep] - r0]))
            heights.append(height[keep])
            gaps.append(gap[keep])
        out = np.full((3, h, w), np.nan, dtype=np.float32)
        points = 0
        if pixels:
            p = np.concatenate(pixels)
            points = len(p)
            out[0] = splat_median(p, np.concatenate(heights), (h, w))[0]
            out[1] = splat_median(p, np.concatenate(gaps), (h, w))[0]
        left, right = self.orthos()
        t = Affine(*self.grid_transform[:6]) @ Affine.translation(c0, r0)
        grid = MapGrid(to_pyproj_crs(left.info.crs), t, w, h)
        measured = np.isfinite(out[0])
        out[2] = overlap_mask(grid, left.sensor, right.sensor, self.overlap_height) | measured
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


# ------------------------------------------------------------------ step 2, the runner
def linear_histogram(values: np.ndarray, bin_width: float) -> dict[int, int]:
    """Sparse histogram of ``values`` in bins ``[k w, (k + 1) w)``."""
    values = np.asarray(values, dtype=np.float64)
    bins, counts = np.unique(np.floor(values[np.isfinite(values)] / bin_width).astype(np.int64),
                             return_counts=True)
    return dict(zip(bins.tolist(), counts.tolist(), strict=True))


def linear_histogram_median(histogram: dict[int, int], bin_width: float) -> float:
    """Median of the values behind a merged :func:`linear_histogram` (linear in a bin)."""
    bins = np.array(sorted(histogram))
    counts = np.array([histogram[b] for b in bins], dtype=np.float64)
    before = np.cumsum(counts) - counts
    half = 0.5 * counts.sum()
    i = int(np.searchsorted(before + counts, half))
    return float((bins[i] + min(max((half - before[i]) / counts[i], 0.0), 1.0)) * bin_width)


def _merge(total: dict, part: dict) -> None:
    for key, count in part.items():
        total[key] = total.get(key, 0) + count


def gap_statistics(cache: TileCache, tiles, gsd: float, max_gap: float | None
                   ) -> tuple[float, float, int]:
    """(threshold, median gap, gaps counted) from the cached points' gaps: ``max_gap``
    when given, else :func:`demtool.dem.sensors.default_max_ray_gap` from histograms."""
    from demtool.dem.sensors import GAP_GSDS, GAP_NMADS

    gaps: dict[str, int] = {}
    for tile in tiles:
        _merge(gaps, log_histogram(cache.load(tile)[3], GAP_BINS_PER_DECADE))
    median = histogram_median([gaps], GAP_BINS_PER_DECADE)
    if median is None:
        return math.inf, math.nan, 0
    if max_gap is not None:
        return float(max_gap), median, sum(gaps.values())
    deviations: dict[str, int] = {}
    for tile in tiles:
        gap = cache.load(tile)[3].astype(np.float64)
        _merge(deviations, log_histogram(np.abs(gap - median), GAP_BINS_PER_DECADE))
    nmad = 1.4826 * (histogram_median([deviations], GAP_BINS_PER_DECADE) or 0.0)
    return median + max(GAP_NMADS * nmad, GAP_GSDS * gsd), median, sum(gaps.values())


def dem_map_tiled(run: Any, params: Any, out: str | os.PathLike, *, disparity_path,
                  left_path, right_path, mask_path=None, error_path=None):
    """The tiled map-projected route (called by
    :func:`demtool.runs.dem_mapprojected.run_dem_mapprojected` after its input checks,
    when :func:`demtool.tiling.wants_tiles` says so).

    Returns
    -------
    demtool.tiled.TiledResult
    """
    with contextlib.ExitStack() as stack:
        return _passes(run, params, out, str(disparity_path), str(left_path),
                       str(right_path), mask_path, error_path, stack)


def _passes(run, params, out, disparity_path: str, left_path: str, right_path: str,
            mask_path, error_path, stack: contextlib.ExitStack):
    from demtool.distributed import run_tiles
    from demtool.errors import ParameterError, ProcessingError
    from demtool.maps import body_from_radii, to_pyproj_crs
    from demtool.maps.grids import snap_grid
    from demtool.mapstereo import map_cells_xy
    from demtool.tiled import TiledOutput, run_tiled
    from demtool.tiled.dem import _local_cluster
    from demtool.tiling import cache_key, work_folder

    if params.mask_band:
        raise ParameterError("--mask-band is not written in tiles: use --interpolated-mask")
    if params.dry_run:
        raise ParameterError("--dry-run: the map-projected route plans its tiles from the "
                             "triangulated points; run without --dry-run")
    if params.projection != "auto":
        raise ParameterError(f"--projection {params.projection}: the map-projected route in "
                             "tiles grids on the orthoimages' map (--projection auto)")
    left, right = _ortho(left_path, "left orthoimage"), _ortho(right_path, "right orthoimage")
    li = left.info
    crs = to_pyproj_crs(li.crs)
    disparity_shape = (li.height, li.width)
    tile_size = int(params.tile_size) or 1024
    points_tiles = plan_tiles(*disparity_shape, tile_size, overlap=0)
    job = MapDemTileJob(disparity_path, left_path, right_path, disparity_shape, tile_size,
                        median_px=params.median)
    inputs = [disparity_path, left_path, right_path]
    workers, scheduler = params.workers, params.scheduler
    if workers >= 2 and not scheduler:  # one cluster, every pass
        scheduler, workers = _local_cluster(stack, job, workers), 0
    # 1. points, outside the lock (as tiled/dem.py's statistics)
    key = cache_key(inputs, params.as_dict(), points_tiles, {"pass": "points"})
    points = TileCache(work_folder(out) / f"{key}-points")
    infos = run_tiles(job.at_step("points"), points_tiles.tiles, points, workers=workers,
                      scheduler=scheduler, log=run.log)
    valid = sum(int(i.get("valid", 0)) for i in infos)
    seen = sum(int(i.get("seen", 0)) for i in infos)
    if valid < 3:
        raise ProcessingError(f"{disparity_path}: fewer than 3 valid disparities")
    if seen < 3:
        raise ProcessingError(f"{disparity_path}: fewer than 3 disparities map back into "
                              "both raw images")
    # 2. statistics
    if params.gsd is not None:
        gsd, gsd_source = float(params.gsd), "--gsd"
    else:
        gsd, gsd_source = float(np.sqrt(abs(li.transform.a * li.transform.e))), "orthoimage"
    max_gap, median_gap, front = gap_statistics(points, points_tiles.tiles, gsd,
                                                params.max_ray_gap)
    if front == 0:
        raise ProcessingError(f"{disparity_path}: no disparity triangulates in front of "
                              "both cameras")
    boxes_xy, heights, kept = [], {}, 0
    for tile in points_tiles.tiles:
        values = points.load(tile).astype(np.float64)
        ok = np.isfinite(values[2]) & (values[3] <= max_gap)
        if not ok.any():
            boxes_xy.append(None)
            continue
        rows, cols = np.nonzero(ok)
        x0, y0 = map_cells_xy(li.transform, rows + tile.core[0], cols + tile.core[2])
        x, y = x0 + values[0][ok], y0 + values[1][ok]
        boxes_xy.append((x.min(), x.max(), y.min(), y.max()))
        _merge(heights, linear_histogram(values[2][ok], HEIGHT_BIN_M))
        kept += int(ok.sum())
    if kept < 3:
        raise ProcessingError(f"only {kept} triangulated points: nothing to grid")
    present = [b for b in boxes_xy if b is not None]
    grid = snap_grid(crs, min(b[0] for b in present), min(b[2] for b in present),
                     max(b[1] for b in present), max(b[3] for b in present), gsd)
    t = grid.transform
    boxes = []
    for b in boxes_xy:  # output cells each points tile can land in (±1 cell)
        if b is None:
            boxes.append(None)
            continue
        cols = sorted(((b[0] - t.c) / t.a, (b[1] - t.c) / t.a))
        rows = sorted(((b[2] - t.f) / t.e, (b[3] - t.f) / t.e))
        boxes.append((math.floor(rows[0]) - 1, math.ceil(rows[1]) + 1,
                      math.floor(cols[0]) - 1, math.ceil(cols[1]) + 1))
    overlap_height = linear_histogram_median(heights, HEIGHT_BIN_M)
    # 3-4. the output grid in tiles
    shape = grid.shape
    factor = coarse_factor(*shape)
    overlap = (default_overlap(params.median, factor) if params.tile_overlap is None
               else params.tile_overlap)
    if params.median > 1 and overlap < params.median // 2:
        raise ParameterError(f"--tile-overlap must be >= {params.median // 2} px (half the "
                             f"--median window), got {overlap}")
    tiling = plan_tiles(*shape, tile_size, overlap=overlap)
    job = replace(job, shape=shape, grid_transform=tuple(t)[:6], points=str(points.folder),
                  boxes=tuple(boxes), max_gap=max_gap, overlap_height=overlap_height,
                  factor=factor)
    parameters = {**params.as_dict(), "max_gap": max_gap, "grid": list(tuple(t)[:6]),
                  "shape": list(shape), "coarse_factor": factor}

    def prepare(fill_job: MapDemTileJob, folder: Path) -> MapDemTileJob:
        return prepare_fill(fill_job.at_step("measure"), fill_job, tiling.tiles, shape,
                            factor, folder, workers=workers, scheduler=scheduler,
                            log=run.log)

    a, b = left.sensor.radii
    body = body_from_radii(a, a, b)
    prov = run.provenance
    route = "disparity-mapprojected"
    outputs = [TiledOutput(out, 0, prov.tags(dem_route=route, gsd_m=gsd, units="metres "
                                             "above the reference sphere", tile_size=tile_size,
                                             **body.tags()), "height")]
    if mask_path is not None:
        outputs.append(TiledOutput(mask_path, 1, prov.tags(
            meaning="1 = interpolated, 0 = measured", **body.tags()), "interpolated"))
    if error_path is not None:
        outputs.append(TiledOutput(error_path, 2, prov.tags(
            meaning="median ray gap of the cell's points", units="metres", **body.tags()),
            "ray_gap"))

    def summarize(fills: list[dict[str, Any]]) -> dict[str, Any]:
        overlap_cells = sum(int(i["cells_overlap"]) for i in fills)
        measured = sum(int(i["cells_measured"]) for i in fills)
        filled = sum(int(i["cells_filled"]) for i in fills)
        return {"route": route, "body": body.name, "crs": crs.name,
                "projection": params.projection, "shape": list(shape), "gsd_m": gsd,
                "gsd_source": gsd_source,
                "behind_camera": sum(int(i.get("behind", 0)) for i in infos),
                "max_ray_gap_m": max_gap,
                "max_ray_gap_source": ("--max-ray-gap" if params.max_ray_gap is not None
                                       else "default"),
                "rejected_ray_gap": front - kept, "median_ray_gap_m": median_gap,
                "points": kept, "interpolated_fraction": filled / max(1, overlap_cells),
                "map_shape": list(shape), "map_gsd_m": gsd, "overlap_cells": overlap_cells,
                "measured_cells": measured, "filled_cells": filled,
                "measured_fraction_of_overlap": measured / max(1, overlap_cells),
                "points_per_measured_cell": kept / max(1, measured),
                "height_min_m": min(float(i["height_min"]) for i in fills),
                "height_max_m": max(float(i["height_max"]) for i in fills),
                "height_median_m": overlap_height, "valid_disparities": valid,
                "unseen_disparities": valid - seen,
                "surfaces": [left.surface, right.surface], "coarse_factor": factor}

    result = run_tiled(run, job, tiling, outputs, inputs=inputs, parameters=parameters,
                       transform=t, crs=crs, workers=workers, scheduler=scheduler,
                       summarize=summarize, prepare=prepare)
    points.remove()
    return result
