"""Runner of ``demtool refine``: shape-from-shading refinement of a DEM with one image.

:func:`run_refine` reads the image and the DEM, resolves sun and view
(:func:`resolve_illumination`), puts the image on the DEM grid
(:func:`image_on_dem_grid`), calls the core (:mod:`demtool.refine`) and writes the
refined DEM, the optional albedo and the sidecar in one transaction.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.refine.inputs import image_on_dem_grid, resolve_illumination
from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.refine import RefineResult
    from demtool.refine.params import RefineParams
    from demtool.tiling.jobs import TiledResult


def run_refine(image_path: str | os.PathLike, dem_path: str | os.PathLike,
               out: str | os.PathLike, params: RefineParams | None = None, *,
               sun_azimuth: float | None = None, sun_elevation: float | None = None,
               sun_vector: tuple[float, float, float] | None = None,
               view_vector: tuple[float, float, float] | None = None,
               albedo_out: str | os.PathLike | None = None,
               sensor_path: str | os.PathLike | None = None,
               resolved: dict[str, Any] | None = None) -> RefineResult | TiledResult:
    """Refine the DEM at ``dem_path`` with the shading of ``image_path``; write ``out``.

    Writes ``out`` (float32 GeoTIFF, the DEM's grid, transform, CRS and tags plus the
    refine parameters, final energies and iteration count), ``<out>.json`` (the
    provenance sidecar with the energies per iteration) and, if asked, the albedo map,
    all in one transaction.  ``params`` defaults to :class:`RefineParams()`; the
    sun and view directions default to the image's tags.

    A DEM on the body's map (with a CRS) takes the map route
    (:mod:`demtool.refine.inputs`): a DEM in degrees is put on a metric grid, the
    image is an orthoimage of ``demtool mapproject`` or a raw image with
    ``sensor_path`` (map-projected here), and the sun and view come from the sensor
    model per point's local east-north-up frame, per tile where they vary.  The refined
    DEM is then on the (metric) map grid.

    Large DEMs run in tiles (``--tile-size``, ``--workers``, ``--scheduler``,
    ``--dry-run``; :mod:`demtool.refine.tiled`), written window by window; the result is
    then a :class:`demtool.tiling.jobs.TiledResult`.

    Raises
    ------
    InputError
        Missing/unreadable files, a NaN-only DEM, grids that cannot be matched.
    ParameterError
        Invalid parameters, no sun direction, a sun below the horizon.
    ProcessingError
        Too many DEM gaps, too few lit pixels.
    """
    import numpy as np

    from demtool import io
    from demtool.errors import InputError, ProcessingError
    from demtool.imaging.checks import check_magnitude, check_texture
    from demtool.refine import refine_heights
    from demtool.refine.params import RefineParams
    from demtool.refine.prepare import prepare_dem

    params = params or RefineParams()
    run = StageRun("refine", params, resolved=resolved,
                   inputs={"IMAGE": image_path, "DEM": dem_path, "--sensor": sensor_path},
                   outputs={"--out": out, "--albedo-out": albedo_out,
                            "sidecar": sidecar_path(out)})
    log, prov = run.log, run.provenance
    from demtool import tiling

    shape = tiling.raster_shape(dem_path, "DEM")
    if tiling.wants_tiles(*shape, params):  # large DEMs: tiles, Dask (docs/stages/scale.md)
        from demtool.refine.tiled import refine_tiled

        return refine_tiled(run, image_path, dem_path, out, params, shape,
                            sun_azimuth=sun_azimuth, sun_elevation=sun_elevation,
                            sun_vector=sun_vector, view_vector=view_vector,
                            albedo_out=albedo_out, sensor_path=sensor_path)
    from demtool.tiling.tasks import numba_threads_at_most

    # --workers N: the kernels of this run on N threads, the caller's count restored after
    with numba_threads_at_most(int(params.workers or 0)):
        dem = io.read_raster(dem_path, what="DEM")
        check_magnitude(dem.data, dem_path, what="DEM")
        map_route = None
        map_report: dict[str, Any] = {}
        if dem.crs is not None:
            from demtool.refine.inputs import metric_dem, resolve_map_route

            dem, converted = metric_dem(dem, log)
            map_report["dem_converted"] = converted
            if sensor_path is not None or (sun_vector is None and sun_azimuth is None):
                map_route = resolve_map_route(image_path, dem, params, log,
                                              sensor_path=sensor_path)
                map_report.update(map_route.report)
                if map_route.windows is not None and albedo_out is not None:
                    from demtool.errors import ParameterError

                    raise ParameterError("--albedo-out: not written when the DEM is refined per "
                                         "tile (the sun or view varies by more than "
                                         "--max-illumination-change over it)")
        elif sensor_path is not None:
            raise InputError(f"{dem_path}: --sensor needs a DEM on the body's map (a planetary "
                             "CRS); this DEM is in an image frame")
        if map_route is not None:
            image_tags: dict[str, str] = {}
            values, note = map_route.values, None
            check_texture(values, image_path, what="image")
            illumination = map_route.illuminations[0]
            sources = {"sun": f"sensor model {map_route.report['sensor']}",
                       "view": f"sensor model {map_route.report['sensor']}"}
        else:
            image = io.read_image(image_path, what="image")
            check_texture(image.data, image_path, what="image")
            image_tags = image.tags
            illumination, sources = resolve_illumination(
                image, sun_azimuth=sun_azimuth, sun_elevation=sun_elevation,
                sun_vector=sun_vector, view_vector=view_vector)
            values, note = image_on_dem_grid(image, dem)
            if note:
                log.warning("%s and %s are on different grids: %s", image.path, dem.path, note)
        log.info("sun %s from %s; view %s from %s", np.round(illumination.sun, 4).tolist(),
                 sources["sun"], np.round(illumination.view, 4).tolist(), sources["view"])
        spacing = dem.spacing
        if not all(np.isfinite(s) and s > 0 for s in spacing):
            raise InputError(f"{dem.path}: the DEM's transform has no usable pixel spacing "
                             f"({spacing})")
        try:
            with run.phase("prepare_dem"):
                prepared = prepare_dem(dem.data, median_size=params.median,
                                       spike_threshold=params.spike_threshold,
                                       start_sigma=params.start_sigma,
                                       max_nan_fraction=params.max_nan_fraction)
        except ProcessingError as exc:
            raise ProcessingError(f"{dem.path}: {exc}") from None
        with run.phase("sfs"):
            if map_route is not None and map_route.windows is not None:
                from dataclasses import replace

                from demtool.refine.tiles import refine_tiles

                blended, tile_results = refine_tiles(
                    values, prepared.dem, spacing=spacing, windows=map_route.windows,
                    illuminations=map_route.illuminations, parameters=params.sfs(),
                    initial=prepared.initial)
                centre = tile_results[len(tile_results) // 2]
                result = replace(centre, dem=blended,
                                 iterations=max(r.iterations for r in tile_results),
                                 converged=all(r.converged for r in tile_results))
                map_report["tile_iterations"] = [r.iterations for r in tile_results]
            else:
                result = refine_heights(values, prepared.dem, spacing=spacing,
                                        illumination=illumination, parameters=params.sfs(),
                                        initial=prepared.initial)
        log.info("DEM preparation (gap filling, median) %.1f s, shape from shading %.1f s",
                 run.timings["prepare_dem"], run.timings["sfs"])
        shift = float(np.mean(result.dem, dtype=np.float64) - np.mean(prepared.dem,
                                                                      dtype=np.float64))
        change = result.dem.astype(np.float64) - prepared.dem
        summary = {
            "iterations": result.iterations, "converged": result.converged,
            "stop_reason": result.stop_reason,
            "energies_final": result.energies.as_dict(),
            "energies_initial": result.initial_energies.as_dict(),
            "energy_history": [e.total for e in result.history],
            "intensity_residual_rms": result.intensity_rms,
            "shadow_fraction": float(result.shadow.mean()),
            "dem_nan_fraction_filled": prepared.nan_fraction,
            "dem_spike_fraction": float(prepared.spikes.mean()),
            "mean_height_shift_m": shift,
            "rms_height_change_m": float(np.sqrt(np.mean(change**2))),
            "sun_vector_grid": illumination.sun.tolist(), "sun_source": sources["sun"],
            "view_vector_grid": illumination.view.tolist(), "view_source": sources["view"],
            "sun_elevation_deg": illumination.sun_elevation_deg,
            "sun_azimuth_deg": illumination.sun_azimuth_deg,
            "phase_deg": illumination.phase_deg,
            "spacing_m": list(spacing), "grid": list(dem.data.shape),
            "image_resampled": note,
            "timings_s": run.timings,  # wall and CPU seconds: prepare_dem, sfs
        }
        if dem.crs is not None:
            summary["map_route"] = map_report
        inherited = {k: v for k, v in dem.tags.items() if not k.startswith("demtool_")}
        tags = {**inherited, **prov.tags(
            frame=dem.tags.get("frame", "unknown"), units="m",
            content="heights refined by shape from shading",
            refine_energies=result.energies.as_dict(), refine_iterations=result.iterations,
            refine_converged=result.converged, sun_vector_grid=illumination.sun.tolist(),
            view_vector_grid=illumination.view.tolist(), reflectance_model=params.model)}
        outputs = [Path(out)]
        with run.transaction():
            with run.phase("write"):
                io.write_raster(out, result.dem, transform=dem.transform, crs=dem.crs, tags=tags)
                if albedo_out is not None:
                    io.write_raster(albedo_out, result.albedo, transform=dem.transform, crs=dem.crs,
                                    tags=prov.tags(frame=dem.tags.get("frame", "unknown"),
                                                   units=f"{image_tags.get('units', 'image unit')} "
                                                         "per unit reflectance",
                                                   content=f"local albedo (Gaussian σ = "
                                                           f"{params.albedo_sigma:g} px) of the "
                                                           "refined DEM"))
                    outputs.append(Path(albedo_out))
            prov.write_sidecar(out, summary, outputs=outputs)
        log.info("wrote %s (%d iterations, mean height shift %.3g m, RMS change %.3g m)", out,
                 result.iterations, shift, summary["rms_height_change_m"])
        return result
