"""The runner of ``demtool dem``'s sensor-model routes in tiles (the job and the steps:
:mod:`demtool.dem.tiled_map`): the points pass, the exact statistics over the cached
points, the output map grid, then :func:`demtool.tiling.jobs.run_tiled` with the fill of
:mod:`demtool.dem.tiled`.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from demtool.dem import tiled as tiled_dem
from demtool.dem.tiled import coarse_factor, default_overlap
from demtool.dem.tiled_grids import prepare_fill
from demtool.dem.tiled_map import (
    LONLAT_FIELDS,
    MapDemTileJob,
    ortho,
    point_fields,
    points_tiling,
    rectified_pair,
    release_points,
    tile_point_count,
    tile_points,
)
from demtool.tiling import TileCache, plan_tiles

MEDIAN_BINS = 4096  # bins of each refinement pass of streaming_median
MEDIAN_COLLECT = 1 << 20  # values gathered in memory for the final selection
#: up to this many values (64 MiB of float64) streaming_median keeps them from its first
#: pass and selects there (the same median, one pass instead of three or more)
MEDIAN_IN_MEMORY = 1 << 23


def streaming_median(chunks: Callable[[], Iterable[np.ndarray]], *, bins: int = MEDIAN_BINS,
                     collect: int = MEDIAN_COLLECT, in_memory: int = MEDIAN_IN_MEMORY
                     ) -> float | None:
    """The exact median (``np.median``'s) of values given in chunks, in bounded memory.

    ``chunks()`` yields the arrays again at each call (one pass each).  A first pass finds
    the count and the range, keeping the values while there are at most ``in_memory``
    of them (then the two middle order statistics are selected there: no second pass);
    otherwise the two middle order statistics are selected by histogram refinement
    (:class:`demtool.compare.streaming.OrderStatistic`, ``bins`` bins a pass, the last
    ``collect`` values gathered and sorted), both from the same passes.  NaNs are
    ignored; None when there is no value.
    """
    from demtool.compare.streaming import OrderStatistic

    def finite():
        for chunk in chunks():
            v = np.asarray(chunk, dtype=np.float64).ravel()
            good = np.isfinite(v)
            yield v if good.all() else v[good]  # (no copy of an all-finite chunk)

    count, lo, hi = 0, math.inf, -math.inf
    kept: list[np.ndarray] | None = []
    for v in finite():
        if v.size:
            count, lo, hi = count + v.size, min(lo, float(v.min())), max(hi, float(v.max()))
            if kept is not None and count <= in_memory:
                kept.append(v)
            else:
                kept = None
    if count == 0:
        return None
    if kept is not None:
        values = np.concatenate(kept)
        ranks = ((count - 1) // 2, count // 2)
        values.partition(ranks)
        return float(0.5 * (values[ranks[0]] + values[ranks[1]]))
    middle = [OrderStatistic(rank, count, lo, hi, bins=bins, gather_limit=collect)
              for rank in ((count - 1) // 2, count // 2)]
    while not all(statistic.done for statistic in middle):
        for v in finite():
            for statistic in middle:
                statistic.add(v)
        for statistic in middle:
            statistic.end_pass()
    return float(0.5 * (middle[0].value + middle[1].value))


def dem_map_tiled(run: Any, params: Any, out: str | os.PathLike, job: MapDemTileJob, *,
                  inputs: list[str], gsd_default: float | None = None,
                  range_to_gsd: float | None = None, crs: Any = None,
                  summary: dict[str, Any] | None = None, mask_path=None, error_path=None):
    """A sensor-model route in tiles, from its points job (``step`` is set here).

    ``gsd_default``, ``range_to_gsd`` and ``crs`` as in
    :func:`demtool.dem.run_sensors.triangulate_to_map`; ``summary``: route fields of the
    sidecar (``route`` first).  With ``--workers N`` (N ≥ 2) every pass runs on threads
    (or one local cluster of processes, where threads cannot be used).

    Returns
    -------
    demtool.tiling.jobs.TiledResult
    """
    with contextlib.ExitStack() as stack:
        return _passes(run, params, out, job, inputs, gsd_default, range_to_gsd, crs,
                       dict(summary or {}), mask_path, error_path, stack)


def _statistics(params, points: TileCache, tiles, gsd: float | None, range_to_gsd, log,
                layout: tuple[str, ...] = LONLAT_FIELDS):
    """(gsd, gsd source, threshold, median gap, front, kept, heights' median); the points
    tiles' fields in ``layout`` (:func:`demtool.dem.tiled_map.point_fields`)."""
    from demtool.mapproject.threads import ordered_map

    front = sum(tile_point_count(points, t, layout) for t in tiles)
    # up to MEDIAN_IN_MEMORY points, each tile's gaps and heights are decoded once, the
    # tiles on every core, and kept for the passes below (the values each pass decoded)
    held: dict[tuple[str, int], np.ndarray] | None = None
    if front <= MEDIAN_IN_MEMORY:
        held = {}
        for t, (gap, height) in zip(tiles, ordered_map(
                lambda t: tile_points(points, t, ("gap", "height"), layout=layout),
                tiles), strict=True):
            held["gap", t.index], held["height", t.index] = gap, height

    def decoded(name: str, t) -> np.ndarray:
        if held is None or name not in ("gap", "height"):
            return tile_points(points, t, (name,), layout=layout)[0]
        return held[name, t.index]

    def band(name: str):
        return lambda: (decoded(name, t) for t in tiles)

    def gap_threshold() -> tuple[float, float, float]:
        """(gsd, median gap, gap threshold)."""
        nonlocal gsd
        if gsd is None:
            gsd = streaming_median(band("range_left")) * range_to_gsd
        median_gap = streaming_median(band("gap"))
        if params.max_ray_gap is not None:
            return gsd, median_gap, float(params.max_ray_gap)
        from demtool.dem.sensors import GAP_GSDS, GAP_NMADS

        deviation = streaming_median(lambda: (np.abs(g - median_gap) for g in band("gap")()))
        return gsd, median_gap, median_gap + max(GAP_NMADS * 1.4826 * deviation,
                                                 GAP_GSDS * gsd)

    every_height = None
    if held is None:  # streamed from the cache: one pass at a time
        gsd, median_gap, max_gap = gap_threshold()
    else:
        # beside the gap medians (one core each: np.partition), the median of every
        # height: the kept heights' when no ray misses by more than the threshold (the
        # same values, so the same median), as is usual; else computed again below
        from demtool.mapproject.threads import available_threads

        (gsd, median_gap, max_gap), every_height = ordered_map(
            lambda task: task(), (gap_threshold, lambda: streaming_median(band("height"))),
            threads=min(2, available_threads()))

    def kept_heights():
        for t in tiles:
            yield decoded("height", t)[decoded("gap", t) <= max_gap]

    kept = sum(int(np.count_nonzero(decoded("gap", t) <= max_gap)) for t in tiles)
    from demtool.dem.sensors import MAX_DROPPED_FRACTION

    if params.max_ray_gap is not None and front - kept > MAX_DROPPED_FRACTION * front:
        from demtool.errors import ParameterError

        raise ParameterError(
            f"--max-ray-gap {max_gap:.3g} m drops {front - kept} of {front} points "
            f"({100.0 * (front - kept) / front:.1f} %; median gap {median_gap:.3g} m): the "
            f"DEM would be interpolated from the {kept} left (at most "
            f"{100 * MAX_DROPPED_FRACTION:.0f} % may be dropped); give a larger --max-ray-gap "
            "or leave it out (median + max(4 NMAD, 2 GSD))")
    log.info("%d correspondences in front of both cameras, %d rays missing by more than "
             "%.3g m (median gap %.3g m, GSD %.3g m)", front, front - kept, max_gap,
             median_gap, gsd)
    overlap_height = (every_height if every_height is not None and kept == front
                      else streaming_median(kept_heights))
    return gsd, max_gap, median_gap, front, kept, overlap_height


def _grid(params, points: TileCache, tiles, body, gsd: float, max_gap: float, crs,
          cached_xy: bool = False, layout: tuple[str, ...] = LONLAT_FIELDS):
    """The output MapGrid and each points tile's box of output cells (None: no point);
    ``cached_xy``: the points tiles hold their map x, y in ``crs`` (not projected again);
    ``layout``: their fields (:func:`demtool.dem.tiled_map.point_fields`)."""
    from demtool.mapproject.threads import ordered_map
    from demtool.maps.frames import unit_vector, xyz_to_lonlat_height
    from demtool.maps.grids import snap_grid
    from demtool.maps.projections import lonlat_to_map, make_projection

    def kept(t):
        lon, lat, gap = tile_points(points, t, ("lon", "lat", "gap"), layout=layout)
        return lon[gap <= max_gap], lat[gap <= max_gap]

    if crs is None or params.projection != "auto":  # as choose_projection: the mean direction
        total, count = np.zeros(3), 0
        for t in tiles:
            lon, lat = kept(t)
            total, count = total + unit_vector(lon, lat).sum(axis=0), count + lon.size
        center_lon, center_lat, _ = xyz_to_lonlat_height(total / count, radii=1.0)
        crs = make_projection(body, params.projection, float(center_lon), float(center_lat))

    def extent(t):
        if cached_xy:
            x, y, gap = tile_points(points, t, ("x", "y", "gap"), layout=layout)
            x, y = x[gap <= max_gap], y[gap <= max_gap]
        else:
            x, y = lonlat_to_map(crs, *kept(t))
            x, y = np.asarray(x), np.asarray(y)
        good = np.isfinite(x) & np.isfinite(y)
        return ((x[good].min(), x[good].max(), y[good].min(), y[good].max())
                if good.any() else None)

    extents = list(ordered_map(extent, tiles))  # the tiles on every core
    present = [b for b in extents if b is not None]
    grid = snap_grid(crs, min(b[0] for b in present), min(b[2] for b in present),
                     max(b[1] for b in present), max(b[3] for b in present), gsd)
    t = grid.transform
    boxes = []
    for b in extents:  # ± 1 cell
        if b is None:
            boxes.append(None)
            continue
        cols = sorted(((b[0] - t.c) / t.a, (b[1] - t.c) / t.a))
        rows = sorted(((b[2] - t.f) / t.e, (b[3] - t.f) / t.e))
        boxes.append((math.floor(rows[0]) - 1, math.ceil(rows[1]) + 1,
                      math.floor(cols[0]) - 1, math.ceil(cols[1]) + 1))
    return grid, tuple(boxes)


def _passes(run, params, out, job: MapDemTileJob, inputs, gsd_default, range_to_gsd, crs,
            route_summary, mask_path, error_path, stack: contextlib.ExitStack):
    from demtool.dem.tiled import _local_cluster
    from demtool.errors import ParameterError, ProcessingError
    from demtool.maps import body_from_radii
    from demtool.tiling import cache_key, work_folder
    from demtool.tiling.distributed import run_tiles
    from demtool.tiling.jobs import TiledOutput, run_tiled

    if params.mask_band:
        raise ParameterError("--mask-band is not written in tiles: use --interpolated-mask")
    overlap = params.tile_overlap
    if overlap is not None and params.median > 1 and overlap < params.median // 2:
        raise ParameterError(f"--tile-overlap must be >= {params.median // 2} px (half the "
                             f"--median window), got {overlap}")
    if crs is not None and params.projection == "auto":  # the map known up front
        from demtool.maps import to_pyproj_crs

        job = replace(job, points_crs_wkt=to_pyproj_crs(crs).to_wkt())
    if params.gsd is not None:
        gsd, gsd_source = float(params.gsd), "--gsd"
    elif gsd_default is not None:
        gsd, gsd_source = float(gsd_default), "orthoimage"
    else:
        gsd, gsd_source = None, "estimated"
    # the fields the later passes read (no longitude, latitude with the map's x, y)
    job = replace(job, point_layout=point_fields(bool(job.points_crs_wkt), gsd is None))
    layout = job.point_layout
    source = job.disparity_path
    tile_size = job.tile_size
    tiling_of_points = points_tiling(*job.disparity_shape, tile_size)
    points_tiles = tiling_of_points.tiles
    if params.dry_run:  # the output grid comes from the points: plan and time the points pass
        run.log.info("dry run: the points pass over the disparity grid (the output map "
                     "grid, about as large, is known after it)")
        return run_tiled(run, job.at_step("points"), tiling_of_points,
                         [TiledOutput(out, 0, {}, "height")], inputs=inputs,
                         parameters=params.as_dict(), dry_run=True)
    workers, scheduler = params.workers, params.scheduler
    from demtool.tiling.local_threads import runs_on_threads

    if workers >= 2 and not scheduler and not runs_on_threads(job, workers, None):
        scheduler, workers = _local_cluster(stack, job, workers), 0  # one, every pass
    # 1. points, outside the lock (as tiled/dem.py's statistics)
    key = cache_key(inputs, params.as_dict(), tiling_of_points,
                    {"pass": "points", "map_xy": job.points_crs_wkt, "fields": layout})
    points = TileCache(work_folder(out) / f"{key}-points")
    from demtool.dem.ahead import FILL_MODULES, import_after_first_tile

    # the tiles this process computes are also kept decoded for the passes below (those
    # a resumed run finds cached are read from the cache): forgotten when the run ends
    stack.callback(release_points, str(points.folder))
    # the fill's modules imported beside the points tiles once the first is done, not
    # alone after the measured grid (demtool.dem.ahead)
    infos = run_tiles(job.at_step("points", points=str(points.folder)), points_tiles,
                      points, workers=workers, scheduler=scheduler, log=run.log,
                      on_tile=import_after_first_tile(FILL_MODULES))
    valid = sum(int(i.get("valid", 0)) for i in infos)
    seen = sum(int(i.get("seen", 0)) for i in infos)

    def refuse(message: str) -> ProcessingError:  # the inputs' fault: no cache to resume
        points.remove()
        return ProcessingError(message)

    if valid < 3:
        raise refuse(f"{source}: fewer than 3 valid disparities")
    if seen < 3:
        raise refuse(f"{source}: fewer than 3 disparities map back into both raw images")
    # 2. statistics and the output grid
    if sum(tile_point_count(points, t, layout) for t in points_tiles) == 0:
        raise refuse(f"{source}: no disparity triangulates in front of both cameras")
    gsd, max_gap, median_gap, front, kept, overlap_height = _statistics(
        params, points, points_tiles, gsd, range_to_gsd, run.log, layout)
    if kept < 3:
        raise refuse(f"only {kept} triangulated points: nothing to grid")
    left, _ = job.sensors()
    a, b = left.radii
    body = body_from_radii(a, a, b)
    grid, boxes = _grid(params, points, points_tiles, body, gsd, max_gap, crs,
                        cached_xy=bool(job.points_crs_wkt), layout=layout)
    from demtool import sizes

    # tiled: memory is the tiles'; the file (DEM, mask, error: 4 bytes a cell each) must fit
    run.log.info("map DEM grid: %d x %d cells", grid.shape[1], grid.shape[0])
    try:
        sizes.check_disk(out, 12 * grid.shape[0] * grid.shape[1], what="map DEM",
                         option=gsd_source if gsd_source == "--gsd" else f"{source}'s points")
    except Exception:
        points.remove()
        raise
    # 3-4. the output grid in tiles
    shape = grid.shape
    factor = coarse_factor(*shape)
    overlap = (default_overlap(params.median, factor) if params.tile_overlap is None
               else params.tile_overlap)
    tiling = plan_tiles(*shape, tile_size, overlap=overlap)
    t = grid.transform
    job = replace(job, shape=shape, grid_transform=tuple(t)[:6], crs_wkt=grid.crs.to_wkt(),
                  points=str(points.folder), boxes=boxes, max_gap=max_gap,
                  overlap_height=overlap_height, factor=factor, median_px=params.median)
    parameters = {**params.as_dict(), "max_gap": max_gap, "grid": list(tuple(t)[:6]),
                  "crs": job.crs_wkt, "shape": list(shape), "coarse_factor": factor}

    def prepare(fill_job: MapDemTileJob, folder: Path) -> MapDemTileJob:
        prepared = prepare_fill(fill_job.at_step("measure"), fill_job, tiling.tiles, shape,
                                factor, folder, workers=workers, scheduler=scheduler,
                                log=run.log, sweeps=tiled_dem.SWEEPS)
        release_points(str(points.folder))  # measured: the fill reads no point
        return prepared

    prov = run.provenance
    route = route_summary.get("route", "")
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
        extra = {"unseen_disparities": valid - seen} if job.source == "mapprojected" else {}
        return {**route_summary, "body": body.name, "crs": grid.crs.name,
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
                "height_median_m": overlap_height, "valid_disparities": valid, **extra,
                "coarse_factor": factor}

    result = run_tiled(run, job, tiling, outputs, inputs=inputs, parameters=parameters,
                       transform=t, crs=grid.crs, workers=workers, scheduler=scheduler,
                       summarize=summarize, prepare=prepare)
    points.remove()
    return result


def mapprojected_job(disparity_path, left_path, right_path, tile_size: int
                     ) -> MapDemTileJob:
    """The points job of the map-projected route (the orthoimages already checked)."""
    from demtool import io as dio
    from demtool.mapproject.stereo import row_shift_of

    info = ortho(str(left_path), "left orthoimage").info
    shift = row_shift_of(dio.raster_info(disparity_path, what="disparity").tags)
    return MapDemTileJob("mapprojected", str(disparity_path), (info.height, info.width),
                         tile_size, left_path=str(left_path), right_path=str(right_path),
                         row_shift=shift)


def rectified_job(disparity_path, rectify_path, tile_size: int,
                  bounds: tuple[float, float]) -> MapDemTileJob:
    """The points job of the calibrated rectified route."""
    _, _, geometry = rectified_pair(str(rectify_path))
    width, height = (int(v) for v in geometry.size_rect)
    return MapDemTileJob("rectified", str(disparity_path), (height, width), tile_size,
                         rectify_path=str(rectify_path),
                         disparity_bounds=(float(bounds[0]), float(bounds[1])))
