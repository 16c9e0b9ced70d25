"""Runner of ``demtool mapproject``: an image resampled onto the body's map through its
sensor model, tile by tile (the image, the DEM and the output are read and written in
windows, so neither has to fit in memory)."""

from __future__ import annotations

import contextlib
import math
import os
import time
from concurrent.futures import Future
from concurrent.futures import wait as futures_wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from demtool.mapproject.surface import (
    DEM_TAG,
    HEIGHT_TAG,
    SENSOR_TAG,
    SURFACE_TAG,
    DemSurface,
    require_same_body,
)
from demtool.stagerun import StageRun

if TYPE_CHECKING:
    from demtool.mapproject.params import MapprojectParams


def _footprint_heights(surface: DemSurface | None, height: float, sensor, body):
    """Heights along the image's outer edge, from the DEM where given (two passes), and
    the surface holding the DEM under the footprint in memory (:meth:`DemSurface.holding`:
    read once for the second pass and the tiles)."""
    from demtool.mapproject.core import ground_footprint
    from demtool.maps import xyz_to_lonlat_height

    if surface is None:
        return height, surface
    h: Any = 0.0
    for _ in range(2):
        xyz = ground_footprint(sensor, body.surface, h)
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=body.surface)
        if not isinstance(h, np.ndarray):  # the first pass: the DEM under the footprint
            surface = surface.holding(lon, lat)
        found = surface.heights_lonlat(lon, lat)
        if not isinstance(h, np.ndarray):
            from demtool.mapproject.checks import check_rpc_domain, check_surface_heights

            check_surface_heights(found, surface.info.path, body)
            check_rpc_domain(sensor, body, found, str(surface.info.path))
        fallback = float(np.nanmedian(found)) if np.isfinite(found).any() else 0.0
        h = np.where(np.isfinite(found), found, fallback)
    return h, surface


def _chosen_crs(sensor, body, params, pair_sensor_path, edge_h):
    """The CRS ``--t-srs`` names, or the one ``--pair-sensor`` turns along the pair's
    parallax (:mod:`demtool.mapproject.parallax`); None: the default projection."""
    from demtool.errors import InputError, ParameterError
    from demtool.maps.crs_option import parallax_aligned_crs, parse_t_srs

    if params.t_srs is not None:
        try:
            return parse_t_srs(params.t_srs, body)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
    if pair_sensor_path is None:
        return None
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.parallax import parallax_azimuth
    from demtool.maps import same_body
    from demtool.sensors import read_sensor

    other = read_sensor(pair_sensor_path)
    if other.radii is None or not same_body(sensor_body(other), body):
        raise InputError(f"{pair_sensor_path}: --pair-sensor is not a model of {body.name}")
    try:
        lon, lat, azimuth = parallax_azimuth(sensor, other, body, float(np.mean(edge_h)))
    except ValueError as exc:
        raise InputError(f"{pair_sensor_path}: --pair-sensor: {exc}") from None
    return parallax_aligned_crs(body, lon, lat, azimuth)


def _grid(sensor, body, surface: DemSurface | None, params, log, pair_sensor_path=None):
    """The output grid: the DEM's lattice over the footprint, or a new grid (on
    ``--t-srs``, or along the pair's parallax with ``--pair-sensor``); and the surface,
    holding the DEM under the footprint (:func:`_footprint_heights`)."""
    height = params.height if params.height is not None else 0.0
    edge_h, surface = _footprint_heights(surface, height, sensor, body)
    return _grid_on(sensor, body, surface, params, log, pair_sensor_path, edge_h), surface


def _grid_on(sensor, body, surface: DemSurface | None, params, log, pair_sensor_path,
             edge_h):
    """:func:`_grid`'s grid, from the heights ``edge_h`` along the image's outer edge."""
    from demtool.errors import InputError, ProcessingError
    from demtool.mapproject.core import ground_footprint, ortho_grid
    from demtool.maps import MapGrid, grid_from_lonlat, to_pyproj_crs, xyz_to_lonlat_height

    chosen = _chosen_crs(sensor, body, params, pair_sensor_path, edge_h)
    projected = surface is not None and not surface.geographic
    try:
        if chosen is not None:
            gsd = params.gsd
            if gsd is None and projected:
                gsd = abs(float(surface.info.transform.a))
            return ortho_grid(sensor, body, height=float(np.mean(edge_h)), gsd=gsd,
                              bounds=params.bounds, crs=chosen)
        if projected and params.gsd is None and params.bounds is None:
            info = surface.info
            xyz = ground_footprint(sensor, body.surface, edge_h)
            if not np.isfinite(xyz).all():
                raise ValueError("part of the image does not see the body (limb in view); "
                                 "give --bounds")
            lon, lat, _ = xyz_to_lonlat_height(xyz, radii=body.surface)
            box = grid_from_lonlat(body, lon, lat, abs(info.transform.a),
                                   crs=to_pyproj_crs(info.crs))
            inverse = ~info.transform
            (ca, ra), (cb, rb) = inverse @ (box.transform.c, box.transform.f), inverse @ (
                box.transform.c + box.width * box.transform.a,
                box.transform.f + box.height * box.transform.e)
            c0, c1 = max(math.floor(min(ca, cb)) - 1, 0), min(math.ceil(max(ca, cb)) + 1,
                                                              info.width)
            r0, r1 = max(math.floor(min(ra, rb)) - 1, 0), min(math.ceil(max(ra, rb)) + 1,
                                                              info.height)
            if c1 <= c0 or r1 <= r0:
                raise InputError(f"{info.path}: DEM does not cover the image's footprint")
            from affine import Affine

            transform = info.transform @ Affine.translation(c0, r0)
            log.info("grid: the DEM's lattice over the image's footprint")
            return MapGrid(crs=to_pyproj_crs(info.crs), transform=transform, width=c1 - c0,
                           height=r1 - r0)
        crs = to_pyproj_crs(surface.info.crs) if projected and params.projection == "auto" \
            else None
        mean_h = float(np.mean(edge_h))
        return ortho_grid(sensor, body, height=mean_h, gsd=params.gsd,
                          projection=params.projection, bounds=params.bounds, crs=crs)
    except ValueError as exc:
        raise ProcessingError(f"{sensor.name or 'sensor'}: cannot build the map grid: {exc}"
                              ) from None


def _hash_tags_aside(image_path, sensor_path, dem_path) -> Future:
    """:func:`demtool.mapproject.hashes.hash_tags` computed on a thread beside the sensor
    read and the grid (file reads and SHA-256 release the GIL; the hashes are cached per
    process, so the tile cache's key reuses them): its future."""
    from demtool.mapproject.hashes import hash_tags

    future: Future = Future()

    def work() -> None:
        try:
            future.set_result(hash_tags(image_path, sensor_path, dem_path))
        except BaseException as exc:  # raised where the tags are needed
            future.set_exception(exc)

    from demtool.tiling.side_threads import start_side_thread

    start_side_thread(work, "demtool-hashes")
    return future


def _tsai_on_body(sensor, sensor_path, image_path, dem_path, t_srs, grid_like):
    """A ``.tsai`` camera's body and image size from the other inputs (None for models
    that carry their own; :mod:`demtool.mapproject.tsai_body`)."""
    from demtool import io as dio
    from demtool.mapproject.tsai_body import tsai_on_body
    from demtool.sensors.tsai import TsaiCamera

    if not isinstance(sensor, TsaiCamera) or sensor.radii is not None:
        return None
    info = dio.raster_info(image_path, what="image")
    dem_crs = None if dem_path is None else dio.raster_info(dem_path, what="DEM").crs
    grid_crs = None if grid_like is None else dio.raster_info(grid_like, what="grid raster").crs
    return tsai_on_body(sensor_path, (info.height, info.width), dem_crs=dem_crs, t_srs=t_srs,
                        grid_like_crs=grid_crs)


def _grid_like(path, sensor_path, body, params):
    """The map grid of an existing raster (``--grid-like``)."""
    from demtool import io as dio
    from demtool.errors import InputError, ParameterError
    from demtool.maps import MapGrid, to_pyproj_crs

    if params.gsd is not None or params.bounds is not None:
        raise ParameterError("--grid-like sets the grid: drop --gsd and --bounds")
    info = dio.raster_info(path, what="grid raster")
    crs = None if info.crs is None else to_pyproj_crs(info.crs)
    if crs is None or not crs.is_projected:
        raise InputError(f"{path}: --grid-like needs a raster on a projected map of the body")
    require_same_body(path, crs, body, sensor_path, "a map")
    return MapGrid(crs=crs, transform=info.transform, width=info.width, height=info.height)


def run_mapproject(image_path: str | os.PathLike, sensor_path: str | os.PathLike,
                   out_path: str | os.PathLike, params: MapprojectParams | None = None, *,
                   dem_path: str | os.PathLike | None = None,
                   angles_out: str | os.PathLike | None = None,
                   grid_like: str | os.PathLike | None = None,
                   pair_sensor: str | os.PathLike | None = None,
                   resolved: dict[str, Any] | None = None) -> dict[str, Any]:
    """Map-project IMAGE through SENSOR onto a DEM (or the sphere raised by ``--height``).

    Writes ``out_path`` (float32 orthoimage, NaN where not seen, tagged with the sensor
    model, the surface and the body; see :data:`SENSOR_TAG` …), its sidecar
    ``<out>.json``, and with ``angles_out`` a 3-band raster of incidence, emission and
    phase angles (degrees, relative to the sphere's normal) on the same grid.  With
    ``grid_like`` the grid is that raster's (its CRS, transform and size; a map of the
    sensor's body), so two orthoimages of a stereo pair share one grid.  A new grid is on
    ``params.t_srs`` when given, or, with ``pair_sensor`` (the other image's model), on
    an oblique Mercator whose x axis follows the pair's parallax.

    Returns
    -------
    dict
        The run's summary (grid, valid fraction, lattice steps, timings).
    """
    from demtool import io as dio
    from demtool.errors import InputError, ParameterError
    from demtool.logs import progress
    from demtool.mapproject.core import native_gsd, sensor_body
    from demtool.mapproject.params import MapprojectParams
    from demtool.mapproject.threads import KernelsAhead, warm
    from demtool.mapproject.tiled import (
        MapprojectTileJob,
        engine_tile_size,
        holding_surface,
        mapproject_tiled,
    )
    from demtool.maps import to_pyproj_crs

    setup = time.perf_counter(), time.process_time()
    params = params or MapprojectParams()
    run = StageRun("mapproject", params, resolved=resolved,
                   inputs={"IMAGE": image_path, "--sensor": sensor_path, "--dem": dem_path,
                           "--grid-like": grid_like, "--pair-sensor": pair_sensor},
                   outputs={"--out": out_path, "--angles-out": angles_out})
    log = run.log
    if (dem_path is None) == (params.height is None):
        raise ParameterError("give exactly one of --dem and --height")
    chosen = [name for name, given in (("--t-srs", params.t_srs is not None),
                                       ("--pair-sensor", pair_sensor is not None),
                                       ("--grid-like", grid_like is not None)) if given]
    if len(chosen) > 1:
        raise ParameterError(f"{' and '.join(chosen)} each set the map's CRS: give one")
    from demtool.mapproject.tiled import _sensor as cached_sensor
    from demtool.mapproject.tiled import _surface as cached_surface

    hashes = _hash_tags_aside(image_path, sensor_path, dem_path)
    # read through the tile job's cache: its tiles, in this process, find the model there
    sensor = cached_sensor(str(sensor_path))
    # the tiles' kernels load on a thread of their own while this one prepares the grid
    kernels = KernelsAhead(sensor)
    try:
        tsai = _tsai_on_body(sensor, sensor_path, image_path, dem_path, params.t_srs, grid_like)
        if tsai is not None:
            sensor = cached_sensor(str(sensor_path), tsai.radii, tsai.image_size)
        if sensor.radii is None:
            raise InputError(f"{sensor_path}: is a camera in a local frame, not on a body; "
                             "mapproject needs a planetary sensor model (ISD, cube, .tsai)")
        info = dio.raster_info(image_path, what="image")
        if (info.height, info.width) != sensor.image_size:
            raise InputError(f"{image_path}: image is {info.width} x {info.height} pixels but the "
                             f"sensor model {sensor_path} describes {sensor.samples} x "
                             f"{sensor.lines}")
        body = sensor_body(sensor)
        if params.height is not None:
            from demtool.mapproject.checks import check_height

            check_height(sensor, body, float(params.height))
        radii = None if tsai is None else tsai.radii
        image_size = None if tsai is None else tsai.image_size
        # read through the tile job's cache too (the DEM's checks once per process)
        surface = (cached_surface(str(dem_path), str(sensor_path), radii, image_size)
                   if dem_path is not None else None)
        if grid_like is not None:
            grid = _grid_like(grid_like, sensor_path, body, params)
        else:
            grid, surface = _grid(sensor, body, surface, params, log, pair_sensor)
        from demtool.mapproject.checks import check_mapproject_grid

        check_mapproject_grid(sensor, body, grid, params, dem_path=dem_path, out_path=out_path,
                              bands=1 + (3 if angles_out is not None else 0), log=log)
        same_crs = surface is not None and not surface.geographic and \
            to_pyproj_crs(surface.info.crs) == grid.crs
        gsd = grid.gsd[0]
        log.info("%s -> %d x %d map cells at %.4g m on %s (%s)", Path(image_path).name,
                 grid.width, grid.height, gsd, body.name, grid.crs.name)
        surface_tags = ({SURFACE_TAG: "dem", DEM_TAG: str(Path(dem_path).resolve())}
                        if dem_path is not None else
                        {SURFACE_TAG: "height", HEIGHT_TAG: float(params.height)})
        tags = run.provenance.tags(
            frame="map", **body.tags(), **surface_tags,
            **{SENSOR_TAG: str(Path(sensor_path).resolve())},
            **hashes.result(),
            mapproject_image=str(Path(image_path).resolve()), sensor_name=sensor.name,
            sensor_kind=sensor.kind, image_size=[sensor.lines, sensor.samples])
        try:
            pixels_per_cell = (gsd / native_gsd(sensor, body.surface)) ** 2
        except ValueError:
            pixels_per_cell = 1.0
        job = MapprojectTileJob(str(image_path), str(sensor_path),
                                None if dem_path is None else str(dem_path), params.height,
                                grid.crs.to_wkt(), tuple(grid.transform)[:6], same_crs,
                                params.step, params.tolerance, params.seed,
                                angles=angles_out is not None, pixels_per_cell=pixels_per_cell,
                                sensor_radii=radii, sensor_image_size=image_size)
        head = {"image": Path(image_path).name, "sensor": sensor.name, "body": body.name,
                "crs": grid.crs.name, "width": grid.width, "height": grid.height, "gsd_m": gsd,
                "transform": list(grid.transform)[:6], "surface": surface_tags[SURFACE_TAG]}
        engine_size = engine_tile_size(grid.shape, params)
    finally:  # loaded before the tiles start (none waits for another's load); and no
        # side thread left running after a refusal (tiling.side_threads)
        kernels.wait()
        futures_wait([hashes])
    if engine_size:
        inputs = [p for p in (image_path, sensor_path, dem_path, grid_like) if p is not None]
        warm(sensor)  # the model's lazily cached state, before tiles on threads share it
        with holding_surface(job, surface):
            # (tiles on threads slice the DEM held in memory)
            result = mapproject_tiled(run, job, grid, engine_size, params, out_path=out_path,
                                      angles_out=angles_out, tags=tags, inputs=inputs,
                                      extra_summary=head)
        if result.dry_run is not None:
            return {**head, "dry_run": result.dry_run}
        summary = result.summary
    else:
        timings = {"setup": round(time.perf_counter() - setup[0], 3),
                   "setup_cpu": round(time.process_time() - setup[1], 3)}
        summary = _project_in_process(run, job, sensor, surface, grid, tags, head, params,
                                      out_path, angles_out, progress, timings)
    log.info("%d x %d orthoimage, %.1f %% seen, lattice steps %s, max interpolation error "
             "%.2g px", grid.width, grid.height, 100 * summary["valid_fraction"],
             summary["lattice_steps"], summary["max_interpolation_error_px"])
    return summary


def _project_in_process(run, job, sensor, surface, grid, tags, head, params, out_path,
                        angles_out, progress, timings) -> dict[str, Any]:
    """The default path: the map tiles on every core (threads,
    :func:`demtool.mapproject.threads.ordered_map`), written in order as they finish;
    ``timings`` (the setup's seconds) gain the tiles' wall and CPU seconds."""
    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.mapproject.core import tile_windows
    from demtool.mapproject.threads import available_threads, ordered_map, warm
    from demtool.mapproject.tiled import ANGLE_BANDS, project_window, summarize_tiles

    windows = tile_windows(grid.shape, params.tile_size)
    infos = []
    started, started_cpu = time.perf_counter(), time.process_time()
    outputs = [out_path] + ([angles_out] if angles_out is not None else [])
    with dio.output_transaction(), contextlib.ExitStack() as stack:
        ortho = stack.enter_context(dio.raster_writer(
            out_path, height=grid.height, width=grid.width, transform=grid.transform,
            crs=grid.crs, tags=tags))
        angle_writer = None if angles_out is None else stack.enter_context(
            dio.raster_writer(angles_out, height=grid.height, width=grid.width, count=3,
                              transform=grid.transform, crs=grid.crs,
                              tags={**tags, "bands": list(ANGLE_BANDS)},
                              band_names=list(ANGLE_BANDS)))
        warm(sensor)
        tiles = ordered_map(lambda window: (window, project_window(job, sensor, surface,
                                                                   window)), windows,
                            threads=min(available_threads(), len(windows)))
        for window, (values, info) in progress(tiles, "mapproject tiles", len(windows)):
            infos.append(info)
            ortho.write(values[0], window[0], window[2])
            if angle_writer is not None:
                angle_writer.write(values[1:], window[0], window[2])
        elapsed = time.perf_counter() - started
        cells = grid.width * grid.height
        summary = {**head, **summarize_tiles(infos, cells),
                   "cells_per_second": round(cells / elapsed) if elapsed > 0 else None,
                   "threads": available_threads(),
                   "timings_s": {**timings, "project": round(elapsed, 3),
                                 "project_cpu": round(time.process_time() - started_cpu, 3)}}
        if summary["valid_cells"] == 0:
            raise InputError(f"{job.image_path}: no map cell sees the image (check --dem, "
                             "--height and --bounds)")
        run.provenance.write_sidecar(out_path, summary, outputs=outputs)
    return summary

