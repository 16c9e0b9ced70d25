"""Calibrated branch of ``demtool dem``: a disparity map triangulated through the two
sensor models of a calibrated ``rectify.npz`` onto the body's map.

Called by :func:`demtool.dem.run.run_dem` when the rectification carries its models
(``rectify --sensor-left/--sensor-right``).  The science lives in
:mod:`demtool.dem.sensors` (triangulation, gap test, map gridding) and
:mod:`demtool.rectify.calibrated` (rectified pixel → original pixel).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.dem.inputs import geometry_from_rectification, models_from_rectification

if TYPE_CHECKING:
    from demtool.dem.params import DemParams
    from demtool.sensors.base import SensorModel
    from demtool.stagerun import StageRun

PathLike = str | os.PathLike | None


def run_dem_sensors(run: StageRun, params: DemParams, out, *, disparity_path,
                    rectify_path, rectification: dict, mask_path: PathLike = None,
                    error_path: PathLike = None, up=None,
                    points_out: PathLike = None) -> dict[str, Any]:
    """Triangulate every valid disparity through the models, grid on the map, write.

    Writes OUT (heights above the body's sphere, the body's projected CRS; with
    ``--mask-band`` a second band = filled cells), ``--interpolated-mask`` (1 = filled),
    ``--error-out`` (median ray gap per cell, metres) and the sidecar.  Returns the
    sidecar summary.  With the tile options on a canvas larger than one tile, in tiles
    (:mod:`demtool.dem.tiled_map`).  Models without a body (local frame) go to
    :func:`demtool.dem.run_local.run_dem_local` (``up``, ``points_out``).
    """
    import numpy as np

    from demtool.dem.inputs import read_disparity
    from demtool.errors import ProcessingError
    from demtool.rectify.calibrated import rect_to_pixels, scene_distance

    log = run.log
    left, right = models_from_rectification(rectification, rectify_path)
    if left.radii is None:  # local-frame models (rover, lander, rig): a local grid
        from demtool.dem.run_local import run_dem_local

        return run_dem_local(run, params, out, disparity_path=disparity_path,
                             rectify_path=rectify_path, rectification=rectification,
                             left=left, right=right, up=up, mask_path=mask_path,
                             error_path=error_path, points_out=points_out)
    if up is not None:
        from demtool.errors import ParameterError

        raise ParameterError(f"{rectify_path}: --up belongs to local-frame models; these are "
                             f"on a body ({left.radii[0]:.6g} m), whose DEM is on the body's "
                             "map")
    geometry = geometry_from_rectification(rectification, left, right)
    if points_out is not None and (params.tile_size or params.scheduler or params.dry_run):
        from demtool.errors import ParameterError

        raise ParameterError("--points-out: the points are written by an untiled run; drop "
                             "--tile-size/--scheduler/--dry-run")
    if params.tile_size or params.scheduler or params.dry_run:  # docs/stages/scale.md
        tiled = _tiled(run, params, out, disparity_path, rectify_path, rectification,
                       geometry, mask_path, error_path)
        if tiled is not None:
            return tiled
    disparity = read_disparity(disparity_path, rectify_path, rectification,
                               geometry.size_rect, log)
    d = disparity.data
    rows, cols = np.nonzero(np.isfinite(d))
    if rows.size < 3:
        raise ProcessingError(f"{disparity_path}: fewer than 3 valid disparities")
    x_left = cols.astype(np.float64)
    y = rows.astype(np.float64)
    x_right = x_left - d[rows, cols]
    l_line, l_sample = rect_to_pixels(left, geometry, "left", x_left, y, scene_distance(left))
    r_line, r_sample = rect_to_pixels(right, geometry, "right", x_right, y,
                                      scene_distance(right))
    summary, result, body = triangulate_to_map(
        run, params, left, right, (l_line, l_sample), (r_line, r_sample),
        source=disparity_path, range_to_gsd=1.0 / geometry.f_px)
    summary = {"route": "disparity-sensors", **summary, "valid_disparities": int(rows.size)}
    points = None
    if points_out is not None:
        from demtool.dem.point_cloud import map_points, rectified_brightness

        brightness = rectified_brightness(rectify_path, rows, cols, log)
        points = map_points(result, brightness, source=Path(disparity_path).name)
    write_map_dem(run, params, out, result, summary, body, route="disparity-sensors",
                  mask_path=mask_path, error_path=error_path, points_out=points_out,
                  points=points)
    return summary


def triangulate_to_map(run: StageRun, params: DemParams, left: SensorModel,
                       right: SensorModel, left_pixels, right_pixels, *, source,
                       range_to_gsd: float | None = None, gsd_default: float | None = None,
                       crs: Any = None, timings: dict[str, float] | None = None,
                       ground_rays: tuple | None = None
                       ) -> tuple[dict[str, Any], Any, Any]:
    """Triangulate correspondences (CSM ``(line, sample)`` arrays of each side) through
    the two models, drop points behind a camera or whose rays miss by more than
    ``--max-ray-gap`` (:func:`demtool.dem.sensors.screen_ray_gaps`), grid
    them on the body's map (:func:`demtool.dem.sensors.dem_on_map`).

    The GSD is ``--gsd``, else ``gsd_default``, else the median left range times
    ``range_to_gsd`` (one pixel's angle).  ``crs``: the map's CRS when
    ``--projection auto`` (None: a new one).  ``timings`` (a sidecar's ``timings_s``)
    gains the wall and CPU seconds of the ``triangulate`` and ``grid`` phases.
    ``ground_rays``: the rays instead of the pixels, ``(origin_left, ground_left,
    origin_right, ground_right)`` (:func:`demtool.dem.sensors.triangulate_ground_rays`;
    the pixels are then None).  Returns (summary, MapDem, body).
    """
    import numpy as np

    from demtool.dem.map_parts import finite_points
    from demtool.dem.sensors import (
        dem_on_map,
        points_on_map,
        screen_ray_gaps,
        triangulate_ground_rays,
        triangulate_sensors,
    )
    from demtool.errors import ProcessingError
    from demtool.mapproject.threads import phase
    from demtool.maps import body_from_radii

    log = run.log
    timings = {} if timings is None else timings
    _check_baseline(left, right, source)
    with phase(timings, "triangulate"):
        if ground_rays is not None:
            tri = triangulate_ground_rays(*ground_rays)
            ground_rays = None  # the caller's only reference: free the rays
        else:
            tri = triangulate_sensors(left, right, *left_pixels, *right_pixels)
    finite = finite_points(tri.xyz)  # on row parts: the 0.1 s of one core at 2048²
    in_front = finite & tri.in_front
    if not in_front.any():
        raise ProcessingError(f"{source}: no disparity triangulates in front of both "
                              "cameras")
    if params.gsd is not None:
        gsd, gsd_source = float(params.gsd), "--gsd"
    elif gsd_default is not None:
        gsd, gsd_source = float(gsd_default), "orthoimage"
    else:
        gsd = float(np.median(tri.range_left[in_front]) * range_to_gsd)
        gsd_source = "estimated"
    keep, max_gap, median_gap = screen_ray_gaps(tri.gap, in_front, params.max_ray_gap, gsd)
    log.info("%d correspondences: %d behind a camera, %d rays missing by more than %.3g m "
             "(median gap %.3g m, GSD %.3g m)", finite.size, int((finite & ~tri.in_front).sum()),
             int((in_front & ~keep).sum()), max_gap, median_gap, gsd)
    a, b = left.radii
    body = body_from_radii(a, a, b)
    if getattr(left, "height_reference", "sphere") == "ellipsoid":  # an RPC: geodetic heights
        from dataclasses import replace

        body = replace(body, height_reference="ellipsoid")
    use_crs = crs if params.projection == "auto" else None
    if params.t_srs is not None:
        body, use_crs = t_srs_body(params, body)
    kept = tri.xyz[keep]
    with phase(timings, "grid"):
        placed = points_on_map(kept, body, gsd_m=gsd, projection=params.projection,
                               crs=use_crs)
        _check_map_size(placed.grid, gsd, gsd_source, source, log)
        result = dem_on_map(kept, tri.gap[keep], body, gsd_m=gsd, crs=use_crs,
                            projection=params.projection, left=left, right=right,
                            median_px=params.median, placed=placed)
    # the gridded points' indices into the correspondences given (for --points-out)
    result = result._replace(point_index=np.flatnonzero(keep)[result.point_index])
    summary: dict[str, Any] = {
        "body": body.name,
        "crs": result.grid.crs.name,
        "projection": params.projection,
        "shape": list(result.dem.shape),
        "gsd_m": gsd,
        "gsd_source": gsd_source,
        "behind_camera": int((finite & ~tri.in_front).sum()),
        "max_ray_gap_m": max_gap,
        "max_ray_gap_source": "--max-ray-gap" if params.max_ray_gap is not None else "default",
        "rejected_ray_gap": int((in_front & ~keep).sum()),
        "median_ray_gap_m": median_gap,
        "points": int(keep.sum()),
        "interpolated_fraction": float(result.filled.sum() / max(1, result.overlap.sum())),
        **result.report,
    }
    log.info("%.1f %% of the DEM's cells in the pair's overlap are interpolated (%d of %d)",
             100 * summary["interpolated_fraction"], int(result.filled.sum()),
             int(result.overlap.sum()))
    return summary, result, body


def write_map_dem(run: StageRun, params: DemParams, out, result, summary: dict[str, Any],
                  body, *, route: str, mask_path: PathLike = None,
                  error_path: PathLike = None, points_out: PathLike = None,
                  points: dict[str, Any] | None = None) -> None:
    """Write a DEM on the body's map (OUT, ``--interpolated-mask``, ``--error-out``,
    ``--points-out`` with ``points`` — the keyword arguments of
    :func:`demtool.io.points.write_points` from
    :func:`demtool.dem.point_cloud.map_points` —, the sidecar) in one transaction."""


    log, prov = run.log, run.provenance
    grid = result.grid
    gsd = summary["gsd_m"]
    reference = (f"the {body.radius / 1e3:.1f} km sphere" if body.height_reference == "sphere"
                 else f"the ellipsoid a={body.a:.10g} m, c={body.c:.10g} m")
    log.info("DEM %d×%d on %s, GSD %.4g m, %.1f %% of the overlap measured, heights %.4g … "
             "%.4g m above %s", grid.width, grid.height, grid.crs.name, gsd,
             100 * result.report["measured_fraction_of_overlap"], summary["height_min_m"],
             summary["height_max_m"], reference)
    units = ("metres above the reference sphere" if body.height_reference == "sphere" else
             "metres above the ellipsoid (geodetic)")
    tags = prov.tags(dem_route=route, gsd_m=gsd, units=units, **body.tags())
    from demtool.dem.output import write_dem_rasters

    with run.transaction():
        outputs = write_dem_rasters(run, params, out, result, transform=grid.transform,
                                    crs=grid.crs, tags=tags, mask_path=mask_path,
                                    error_path=error_path, side_tags=body.tags())
        if points_out is not None and points is not None:
            from demtool.io.points import write_points

            write_points(points_out, **points)
            outputs.append(Path(points_out))
        prov.write_sidecar(out, summary, outputs=outputs)


def _tiled(run: StageRun, params: DemParams, out, disparity_path, rectify_path,
           rectification: dict, geometry, mask_path, error_path) -> dict[str, Any] | None:
    """The route in tiles (:mod:`demtool.dem.tiled_map`); None when the rectified canvas
    fits in one tile (the untiled path then runs)."""
    from demtool.dem.tiled import check_disparity_file
    from demtool.dem.tiled_map_run import dem_map_tiled, rectified_job
    from demtool.errors import InputError
    from demtool.tiling import raster_shape, wants_tiles

    width, height = (int(v) for v in geometry.size_rect)
    shape = raster_shape(disparity_path, "disparity")
    if shape != (height, width):
        raise InputError(f"{disparity_path}: disparity is {shape[1]}×{shape[0]} px but "
                         f"{rectify_path} has a {width}×{height} rectified canvas")
    tile_size = wants_tiles(height, width, params)
    if not tile_size:
        return None
    low, high = (float(v) for v in rectification["disparity_range"])
    from demtool import io as dio
    from demtool.dem.inputs import searched_range

    with dio._open_dataset(Path(disparity_path), "disparity") as dataset:
        searched = searched_range(dataset.tags())
    if searched is not None:  # what sgm searched is accepted (see runs.dem.read_disparity)
        low, high = min(low, searched[0]), max(high, searched[1])
    bounds = check_disparity_file(str(disparity_path), (height, width), (low, high),
                                  source=str(rectify_path), log=run.log)
    job = rectified_job(disparity_path, rectify_path, tile_size, bounds)
    result = dem_map_tiled(run, params, out, job,
                           inputs=[str(disparity_path), str(rectify_path)],
                           range_to_gsd=1.0 / geometry.f_px,
                           summary={"route": "disparity-sensors"}, mask_path=mask_path,
                           error_path=error_path)
    return {"dry_run": result.dry_run} if result.dry_run is not None else result.summary


#: peak bytes per map cell of :func:`demtool.dem.sensors.dem_on_map` (gridding moments,
#: 9 float64; the DEM, weights, masks and filling work arrays)
DEM_BYTES_PER_CELL = 160


def t_srs_body(params: DemParams, body):
    """(body, CRS) of ``--t-srs``: the CRS checked against the sensors' body, and the body
    on that CRS's own surface (sphere or ellipsoid), which the heights written are above.
    ParameterError (one line) for a CRS PROJ does not know, not projected, of another body,
    or given with a --projection other than auto."""
    from demtool.errors import ParameterError
    from demtool.maps import body_from_crs
    from demtool.maps.crs_option import parse_t_srs

    if params.projection != "auto":
        raise ParameterError(f"--t-srs {params.t_srs} and --projection {params.projection} "
                             "each set the map: give one")
    try:
        crs = parse_t_srs(params.t_srs, body)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None
    return body_from_crs(crs), crs


def _check_map_size(grid, gsd: float, gsd_source: str, source, log) -> None:
    """State the map DEM's size (``grid``, covering the points) before gridding; refuse
    one beyond the memory budget, naming --gsd when it was given, else the disparity
    whose points spread so far."""
    from demtool import sizes

    height, width = grid.shape
    if gsd_source == "--gsd":
        option, hint = "--gsd", None
    else:
        option = str(source)
        hint = (f"its triangulated points span {width * gsd / 1e3:.4g} x {height * gsd / 1e3:.4g}"
                f" km at the {gsd_source} GSD of {gsd:.4g} m: is it a disparity of this pair? "
                "(or give a coarser --gsd)")
    sizes.check_grid(grid.shape, bytes_per_cell=DEM_BYTES_PER_CELL, what="map DEM",
                     option=option, log=log, hint=hint)


#: baseline / range below which a pair has no usable parallax (B/H 1e-4: 0.1 px of
#: parallax over 1000 px of image width at best)
MIN_BASE_TO_RANGE = 1e-4


def _check_baseline(left, right, source) -> None:
    """Refuse a pair whose two models stand at one place (a zero baseline: one image's
    model given twice, the same orthoimage twice)."""
    import numpy as np

    from demtool.errors import ProcessingError

    try:
        with np.errstate(all="ignore"):
            centres = [np.asarray(m.camera_center(np.array([0.5 * m.lines])),
                                  dtype=np.float64).reshape(-1, 3)[0] for m in (left, right)]
            ground = np.asarray(left.image_to_ground(0.5 * left.lines, 0.5 * left.samples),
                                dtype=np.float64).reshape(3)
    except (AttributeError, ValueError, TypeError):
        return
    base = float(np.linalg.norm(centres[1] - centres[0]))
    distance = float(np.linalg.norm(ground - centres[0]))
    if np.isfinite(base) and np.isfinite(distance) and distance > 0 and \
            base < MIN_BASE_TO_RANGE * distance:
        raise ProcessingError(f"{source}: the two sensor models stand at one place (baseline "
                              f"{base:.3g} m for a range of {distance / 1e3:.4g} km): no "
                              "parallax to triangulate; is one model given twice?")
