"""Map-projected branch of ``demtool dem``: a disparity between two orthoimages (one map
grid, ``x_right = x_left − d`` in map columns) triangulated through the sensor models
the orthoimages were projected with, onto the body's map.

For every valid left cell (row, col) with disparity d, the right cell is
(row, col − d).  Each cell is raised to the surface its orthoimage was projected on
(the DEM or constant height named in its tags, :data:`demtool.mapproject.surface.DEM_TAG`
/ :data:`~demtool.mapproject.surface.HEIGHT_TAG`) and projected into its raw image
through its sensor model (:func:`demtool.mapproject.stereo.raw_coordinates`: exact
projections on a lattice, interpolated within 0.0001 px,
:mod:`demtool.mapproject.lattice`); the two raw
pixels are triangulated as in the calibrated frame route
(:func:`demtool.dem.run_sensors.triangulate_to_map`).  ASP's map-projected stereo
does the same (Beyer et al. 2018, §2.3).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.dem.params import DemParams
    from demtool.stagerun import StageRun

PathLike = str | os.PathLike | None


def run_dem_mapprojected(run: StageRun, params: DemParams, out, *, disparity_path,
                         left_path, right_path, mask_path: PathLike = None,
                         error_path: PathLike = None) -> dict[str, Any]:
    """Triangulate a disparity between two orthoimages through their sensor models,
    grid on the body's map (the orthoimages' CRS unless ``--projection`` says
    otherwise; GSD: ``--gsd`` or the orthoimages'), write OUT (+ mask, error, sidecar).
    Returns the sidecar summary.  With the tile options on a grid larger than one tile,
    in tiles (:mod:`demtool.dem.tiled_map`).
    """
    import numpy as np

    from demtool import io as dio
    from demtool.dem.run_sensors import triangulate_to_map, write_map_dem
    from demtool.dem.tiled_map import ortho
    from demtool.errors import InputError, ProcessingError
    from demtool.mapproject.stereo import check_right_cells, disparity_cells
    from demtool.mapproject.threads import phase
    from demtool.maps import to_pyproj_crs

    log = run.log
    timings: dict[str, float] = {}
    # read once per process (the tiled route's tiles find them in ortho's cache); one
    # after the other: on two threads they ran no faster (the reading, the imports and
    # numba's first kernel load hold the GIL)
    left = ortho(str(left_path), "left orthoimage")
    right = ortho(str(right_path), "right orthoimage")
    li, ri = left.info, right.info
    from demtool.mapproject.hashes import check_distinct, check_pair_order

    check_distinct(left_path, li.tags, right_path, ri.tags)
    if (li.transform != ri.transform or (li.width, li.height) != (ri.width, ri.height)
            or to_pyproj_crs(li.crs) != to_pyproj_crs(ri.crs)):
        raise InputError(f"{left_path} and {right_path}: the orthoimages are on different "
                         "map grids (map-project the right one with --grid-like LEFT)")
    if left.sensor.radii is None or right.sensor.radii is None:
        raise InputError(f"{left_path}: its sensor models are not on a body")
    check_pair_order(disparity_path, left_path, right_path)
    if params.tile_size or params.scheduler or params.dry_run:  # docs/stages/scale.md
        tiled = _tiled(run, params, out, disparity_path, left_path, right_path, li,
                       mask_path, error_path)
        if tiled is not None:
            return tiled
    with phase(timings, "read"):
        disparity = dio.read_raster(disparity_path, what="disparity")
    if (disparity.data.shape != (li.height, li.width) or disparity.transform != li.transform
            or disparity.crs is None or to_pyproj_crs(disparity.crs) != to_pyproj_crs(li.crs)):
        raise InputError(f"{disparity_path}: disparity is not on the grid of the left "
                         f"orthoimage {left_path} ({disparity.data.shape[1]}×"
                         f"{disparity.data.shape[0]} vs {li.width}×{li.height} cells, or "
                         "another transform/CRS); match the orthoimages with demtool sgm")
    rows, l_cols, r_cols = disparity_cells(disparity.data)
    check_right_cells(disparity_path, right_path, l_cols, r_cols, ri.width)
    if rows.size < 3:
        raise ProcessingError(f"{disparity_path}: fewer than 3 valid disparities")
    from demtool.mapproject.stereo import row_shift_of

    r_rows = rows + row_shift_of(disparity.tags)  # sgm's shift of the right ortho, if any
    crs = to_pyproj_crs(li.crs)
    from demtool.dem.ahead import FILL_MODULES, import_ahead
    from demtool.dem.ortho_rays import ortho_rays

    ahead = import_ahead(FILL_MODULES)  # beside the rays (nogil kernels), not in the grid
    try:
        with phase(timings, "coordinates"):  # phase (joined before it)
            found = ortho_rays(left, right, crs, rows, l_cols, r_rows, r_cols)
    finally:  # also when the rays fail: no import left running after the error
        ahead.join()
    seen = found.seen
    log.info("%d valid disparities, %d seen by both sensors", rows.size, int(seen.sum()))
    if seen.sum() < 3:
        raise ProcessingError(f"{disparity_path}: fewer than 3 disparities map back into "
                              "both raw images")
    gsd = float(np.sqrt(abs(li.transform.a * li.transform.e)))
    route = {"route": "disparity-mapprojected"}
    counts = {"valid_disparities": int(rows.size), "unseen_disparities": int((~seen).sum()),
              "surfaces": [left.surface, right.surface],
              "raw_coordinates_max_error_px": found.max_error_px(),
              "ray_origin_max_miss_m": max(found.left.max_origin_miss_m,
                                           found.right.max_origin_miss_m),
              "raw_coordinates_exact": found.left.exact_points + found.right.exact_points}
    rays, found = [found.rays()], None  # held by the call alone: freed once triangulated
    summary, result, body = triangulate_to_map(
        run, params, left.sensor, right.sensor, None, None, source=disparity_path,
        gsd_default=gsd, crs=crs, timings=timings, ground_rays=rays.pop())
    summary = {**route, **summary, **counts}
    summary.update(_pair_precision(run, left, right, crs, li, gsd))
    summary["timings_s"] = timings
    write_map_dem(run, params, out, result, summary, body, route="disparity-mapprojected",
                  mask_path=mask_path, error_path=error_path)
    return summary


def _check_disparity_grid(disparity_path, left_path, li, shape, transform, crs) -> None:
    from demtool.errors import InputError
    from demtool.maps import to_pyproj_crs

    if (shape != (li.height, li.width) or transform != li.transform or crs is None
            or to_pyproj_crs(crs) != to_pyproj_crs(li.crs)):
        raise InputError(f"{disparity_path}: disparity is not on the grid of the left "
                         f"orthoimage {left_path} ({shape[1]}×{shape[0]} vs "
                         f"{li.width}×{li.height} cells, or another transform/CRS); match "
                         "the orthoimages with demtool sgm")


def _tiled(run: StageRun, params: DemParams, out, disparity_path, left_path, right_path,
           li, mask_path, error_path) -> dict[str, Any] | None:
    """The route in tiles (:mod:`demtool.dem.tiled_map`); None when the orthoimages' grid
    fits in one tile (the untiled path then runs)."""
    import numpy as np

    from demtool import io as dio
    from demtool.dem.tiled_map import ortho
    from demtool.dem.tiled_map_run import dem_map_tiled, mapprojected_job
    from demtool.tiling import wants_tiles

    info = dio.raster_info(disparity_path, what="disparity")
    _check_disparity_grid(disparity_path, left_path, li, (info.height, info.width),
                          info.transform, info.crs)
    tile_size = wants_tiles(li.height, li.width, params)
    if not tile_size:
        return None
    job = mapprojected_job(disparity_path, left_path, right_path, tile_size)
    result = dem_map_tiled(
        run, params, out, job, inputs=[str(disparity_path), str(left_path), str(right_path)],
        gsd_default=float(np.sqrt(abs(li.transform.a * li.transform.e))),
        crs=_tiled_crs(params, ortho(str(left_path), "left orthoimage").sensor, li),
        summary={
            "route": "disparity-mapprojected",
            "surfaces": [ortho(str(p), w).surface for p, w in (
                (left_path, "left orthoimage"), (right_path, "right orthoimage"))]},
        mask_path=mask_path, error_path=error_path)
    return {"dry_run": result.dry_run} if result.dry_run is not None else result.summary


def _tiled_crs(params, sensor, li):
    """The tiled route's map CRS: ``--t-srs`` (checked), else the orthoimages'."""
    from demtool.maps import to_pyproj_crs

    if params.t_srs is None:
        return to_pyproj_crs(li.crs)
    from demtool.dem.run_sensors import t_srs_body
    from demtool.mapproject.core import sensor_body

    return t_srs_body(params, sensor_body(sensor))[1]


def _pair_precision(run: StageRun, left, right, crs, li, gsd: float) -> dict[str, Any]:
    """The pair's convergence at the map's centre and the height one map pixel of
    parallax stands for (:func:`demtool.sensors.isis_cam2map.parallax_precision`),
    logged and returned for the sidecar."""
    import numpy as np

    from demtool.mapproject.stereo import map_cells_xy
    from demtool.maps import map_to_xyz
    from demtool.sensors.isis_cam2map import parallax_precision

    x, y = map_cells_xy(li.transform, np.array([li.height / 2.0]), np.array([li.width / 2.0]))
    xyz = map_to_xyz(crs, x, y, left.heights(x, y)).reshape(3)
    try:
        found = parallax_precision(left.sensor, right.sensor, xyz)
    except (ValueError, FloatingPointError):
        return {}
    per_px = found["height_per_px_parallax_factor"] * gsd
    if not (np.isfinite(per_px) and np.isfinite(found["convergence_deg"])):
        return {}  # models without a camera position (RPC): no convergence to tell
    run.log.info("convergence %.2f° at the map centre: one pixel (%.3g m) of parallax is "
                 "%.3g m of height", found["convergence_deg"], gsd, per_px)
    return {"convergence_deg": found["convergence_deg"], "height_per_px_parallax_m": per_px}
