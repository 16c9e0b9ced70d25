"""Runner of ``demtool dem``: a dense DEM in the target frame from bundle points (BAM
route) or from a disparity map (SIAM routes: projective fit or triangulation)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.dem.inputs import (
    check_pair_cameras,
    pair_names,
    read_disparity,
    searched_range,
)
from demtool.stagerun import StageRun, sidecar_path
from demtool.synth.folder import read_scene_description, scene_number

if TYPE_CHECKING:
    from demtool.dem import OutlierOptions
    from demtool.dem.params import DemParams
    from demtool.dem.run_dense import PathPair


#: a points-route DEM measured on less than this share of its cells gets a warning
SPARSE_MEASURED = 0.05


def _points_route(points_path: str | os.PathLike, *, target: str | None,
                  distance_m: float | None, scene: dict[str, Any],
                  scene_path: str | os.PathLike | None, outliers: OutlierOptions,
                  median_px: int, dense: Sequence[PathPair] = (),
                  max_ray_gap: float | None = None
                  ) -> tuple[Any, str, str, float, dict[str, Any]]:
    """BAM route: (DemResult, target name, route tag, estimated GSD, extra summary);
    densified by the ``dense`` pairs (disparity, rectify.npz) when given."""
    import numpy as np

    from demtool import dem as core
    from demtool import io as dio
    from demtool.errors import InputError, ParameterError
    from demtool.sensors.pinhole import cameras_from_arrays

    bundle = dio.read_npz(points_path, "bundle")
    names = [str(n) for n in bundle["image_names"]]
    cameras = cameras_from_arrays(bundle)
    target_name = target or names[int(bundle["target_index"])]
    if target_name not in cameras:
        raise InputError(f"{points_path}: target {target_name} is not among the registered "
                         f"images ({', '.join(names)})")
    index = names.index(target_name)
    aligned = bool(bundle["aligned"])
    distortion = (bundle["distortion"][index] if "distortion" in bundle
                  else np.zeros(2))
    if not aligned and distance_m is None:
        distance_m = scene_number(scene, scene_path, "distance_m")
        if distance_m is None:
            raise ParameterError("the bundle is not aligned: give the spacecraft-surface "
                                 "distance with --distance or --scene scene.json")
    camera = cameras[target_name]
    if dense:
        from demtool.dem.dense import dem_from_points_dense
        from demtool.dem.run_dense import read_dense_pairs
        from demtool.logs import get_logger

        pairs = read_dense_pairs(dense, cameras, points_path, get_logger("dem"))
        result = dem_from_points_dense(bundle["points"], cameras, target_name, pairs,
                                       aligned=aligned, distance_m=distance_m,
                                       distortion=distortion, outliers=outliers,
                                       median_px=median_px, max_ray_gap=max_ray_gap)
    else:
        result = core.dem_from_points(bundle["points"], camera, aligned=aligned,
                                      distance_m=distance_m, distortion=distortion,
                                      outliers=outliers, median_px=median_px)
    estimated_gsd = core.estimate_gsd(camera, aligned=aligned,
                                      depth=np.array([result.report["median_depth"]]),
                                      distance_m=distance_m)
    route = ("points-metric" if aligned else "points-eq2") + ("-dense" if dense else "")
    return result, target_name, route, estimated_gsd, {"distance_m": distance_m}


def _pair_cameras(cameras_path, rectify_path, rectification: dict, left_name: str,
                  right_name: str) -> dict:
    """The pair's cameras from cameras.npz, checked against the rectification's sizes."""
    from demtool import io as dio
    from demtool.sensors.pinhole import cameras_from_arrays

    cameras = cameras_from_arrays(dio.read_npz(cameras_path, "cameras"))
    check_pair_cameras(cameras, cameras_path, rectify_path, rectification, left_name,
                       right_name)
    return cameras


def _tiled_pair(disparity_path, rectify_path, cameras_path, target: str | None) -> Any:
    """The checked inputs of the tiled calibrated route (:mod:`demtool.dem.tiled`),
    read without the disparity's pixels."""
    from demtool import io as dio
    from demtool.dem.tiled import TiledPair
    from demtool.errors import InputError
    from demtool.tiling import raster_shape

    rectification = dio.read_npz(rectify_path, "rectification")
    width_rect, height_rect = (int(v) for v in rectification["size_rect"])
    shape = raster_shape(disparity_path, "disparity")
    if shape != (height_rect, width_rect):
        raise InputError(f"{disparity_path}: disparity is {shape[1]}×{shape[0]} px but "
                         f"{rectify_path} has a {width_rect}×{height_rect} rectified canvas")
    with dio._open_dataset(Path(disparity_path), "disparity") as dataset:
        tags = dataset.tags()
        frame = tags.get("frame", "")
    left_name, right_name, target_name, side = pair_names(
        disparity_path, rectify_path, rectification, frame, target)
    cameras = _pair_cameras(cameras_path, rectify_path, rectification, left_name, right_name)
    low, high = (float(v) for v in rectification["disparity_range"])
    searched = searched_range(tags)
    if searched is not None:  # what sgm searched is accepted (see read_disparity)
        low, high = min(low, searched[0]), max(high, searched[1])
    return TiledPair(str(disparity_path), str(rectify_path), str(cameras_path),
                     rectification["H_left"], rectification["H_right"], cameras[left_name],
                     cameras[right_name], side, target_name, (height_rect, width_rect),
                     (low, high))


def _disparity_route(disparity_path: str | os.PathLike, rectify_path: str | os.PathLike, *,
                     reference_path: str | os.PathLike | None,
                     cameras_path: str | os.PathLike | None, target: str | None,
                     outliers: OutlierOptions, median_px: int, seed: int,
                     max_ray_gap: float | None = None
                     ) -> tuple[Any, str, str, float, dict[str, Any]]:
    """SIAM routes: (DemResult, target name, route tag, estimated GSD, extra summary)."""

    from demtool import dem as core
    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.imaging.checks import check_magnitude
    from demtool.logs import get_logger

    rectification = dio.read_npz(rectify_path, "rectification")
    disparity = read_disparity(disparity_path, rectify_path, rectification,
                               rectification["size_rect"], get_logger("dem"))
    left_name, right_name, target_name, side = pair_names(
        disparity_path, rectify_path, rectification, disparity.tags.get("frame", ""), target)
    width, height = (int(v) for v in rectification[f"size_{side}"])
    H_left, H_right = rectification["H_left"], rectification["H_right"]
    if cameras_path is not None:
        cameras = _pair_cameras(cameras_path, rectify_path, rectification, left_name,
                                right_name)
        result = core.dem_from_disparity_calibrated(
            disparity.data, H_left, H_right, cameras[left_name], cameras[right_name],
            target=side, outliers=outliers, median_px=median_px, max_ray_gap=max_ray_gap)
        target_camera = cameras[target_name]
        estimated_gsd = result.report["median_depth_m"] * core.points.pixel_angle(target_camera)
        return result, target_name, "disparity-calibrated", estimated_gsd, {}
    reference = dio.read_raster(reference_path, what="reference DEM")
    check_magnitude(reference.data, reference_path, what="reference DEM")
    if reference.data.shape != (height, width):
        raise InputError(f"{reference_path}: reference DEM is {reference.data.shape[1]}×"
                         f"{reference.data.shape[0]} px but the target image {target_name} is "
                         f"{width}×{height}; it must be on the target's pixel grid")
    frame = reference.tags.get("frame")
    if frame is not None and frame != f"image:{target_name}":
        raise InputError(f"{reference_path}: reference DEM is in frame {frame}, expected "
                         f"image:{target_name}")
    result = core.dem_from_disparity_projective(
        disparity.data, H_left, H_right, reference.data, target=side, outliers=outliers,
        median_px=median_px, seed=seed)
    return result, target_name, "disparity-projective", reference.spacing[0], {}


PathLike = str | os.PathLike | None


def run_dem(out: str | os.PathLike, params: DemParams | None = None, *,
            points_path: PathLike = None, disparity_path: PathLike = None,
            rectify_path: PathLike = None, reference_path: PathLike = None,
            cameras_path: PathLike = None, scene_path: PathLike = None,
            mask_path: PathLike = None, error_path: PathLike = None,
            mapprojected: tuple[str | os.PathLike, str | os.PathLike] | None = None,
            up: tuple[float, float, float] | None = None, points_out: PathLike = None,
            dense: Sequence[PathPair] = (), resolved: dict | None = None) -> dict:
    """Run the dem stage: read the inputs, build the DEM, write it with its sidecar.

    Give ``points_path`` (BAM route) or ``disparity_path`` with ``rectify_path`` and
    one of ``reference_path`` (projective fit) or ``cameras_path`` (triangulation), or
    neither with a calibrated ``rectify_path`` (sensor models: a DEM on the body's map,
    :func:`demtool.dem.run_sensors.run_dem_sensors`; ``error_path`` writes its
    triangulation-error raster; models without a body give a DEM on a local metric grid,
    heights along ``up`` (default the frame's +Z), and ``points_out`` writes the points
    as PLY, :func:`demtool.dem.run_local.run_dem_local`), or ``disparity_path`` with
    ``mapprojected`` = (left orthoimage, right orthoimage) from ``demtool mapproject``
    (a DEM on the body's map, :func:`demtool.dem.run_mapprojected.run_dem_mapprojected`).
    With ``points_path``, ``dense`` = ((disparity, rectify.npz), …), pairs of the block,
    densifies the BAM DEM (:mod:`demtool.dem.dense`).
    ``mask_path`` also writes the interpolation mask.
    Returns the sidecar summary.
    """
    import numpy as np

    from demtool import io as dio
    from demtool.dem.params import DemParams

    params = params or DemParams()
    run = StageRun("dem", params, resolved=resolved,
                   inputs={"--points": points_path, "--disparity": disparity_path,
                           "--rectify": rectify_path, "--reference": reference_path,
                           "--cameras": cameras_path, "--scene": scene_path,
                           "--mapprojected LEFT": mapprojected[0] if mapprojected else None,
                           "--mapprojected RIGHT": mapprojected[1] if mapprojected else None,
                           "--dense": [path for pair in dense for path in pair] or None},
                   outputs={"--out": out, "--interpolated-mask": mask_path,
                            "--error-out": error_path, "--points-out": points_out,
                            "sidecar": sidecar_path(out)})
    log, prov = run.log, run.provenance
    if points_out is not None:
        from demtool.io.points import check_points_path

        check_points_path(points_out)  # before any work: PLY, LAS or LAZ
    for path in run.input_paths():
        dio.require_file(path, "input file")
    if dense and points_path is None:
        from demtool.errors import ParameterError

        raise ParameterError("--dense densifies the BAM route: it needs --points bundle.npz")
    if disparity_path is not None and mapprojected is not None:
        from demtool.dem.run_mapprojected import run_dem_mapprojected
        from demtool.errors import ParameterError

        if rectify_path or reference_path or cameras_path:
            raise ParameterError("--mapprojected takes no --rectify, --reference or --cameras")
        if up is not None or points_out is not None:
            raise ParameterError("--up belongs to the local-frame route and --points-out to "
                                 "--disparity with a calibrated rectify.npz, not to "
                                 "--mapprojected")
        return run_dem_mapprojected(run, params, out, disparity_path=disparity_path,
                                    left_path=mapprojected[0], right_path=mapprojected[1],
                                    mask_path=mask_path, error_path=error_path)
    if disparity_path is not None:
        from demtool.dem.inputs import is_calibrated
        from demtool.dem.run_sensors import run_dem_sensors
        from demtool.errors import ParameterError

        rectification = dio.read_npz(rectify_path, "rectification")
        if is_calibrated(rectification):
            if reference_path is not None or cameras_path is not None:
                raise ParameterError(f"{rectify_path} is calibrated (it carries the sensor "
                                     "models): drop --reference/--cameras")
            return run_dem_sensors(run, params, out, disparity_path=disparity_path,
                                   rectify_path=rectify_path, rectification=rectification,
                                   mask_path=mask_path, error_path=error_path, up=up,
                                   points_out=points_out)
        if reference_path is None and cameras_path is None:
            raise ParameterError(f"{rectify_path} is not calibrated: give --reference or "
                                 "--cameras (or rectify with --sensor-left/--sensor-right)")
        if error_path is not None:
            raise ParameterError("--error-out belongs to the sensor-model route (a calibrated "
                                 "rectify.npz)")
    if up is not None or points_out is not None:
        from demtool.errors import ParameterError

        raise ParameterError("--up belongs to the local-frame route and --points-out to the "
                             "calibrated ones (--disparity with a calibrated rectify.npz)")
    scene = read_scene_description(scene_path) if scene_path is not None else {}
    if _tile_options(params):  # large images: tiles over the output grid (docs/stages/scale.md)
        tiled = _dem_tiled(run, params, out, disparity_path=disparity_path,
                           rectify_path=rectify_path, cameras_path=cameras_path,
                           scene=scene, scene_path=scene_path, mask_path=mask_path)
        if tiled is not None:
            return tiled
    outliers = params.outliers()
    target, median_px, mask_band = params.target, params.median, params.mask_band
    if points_path is not None:
        result, target_name, route, estimated_gsd, extra = _points_route(
            points_path, target=target, distance_m=params.distance, scene=scene,
            scene_path=scene_path, outliers=outliers, median_px=median_px, dense=dense,
            max_ray_gap=params.max_ray_gap)
    else:
        result, target_name, route, estimated_gsd, extra = _disparity_route(
            disparity_path, rectify_path, reference_path=reference_path,
            cameras_path=cameras_path, target=target, outliers=outliers,
            median_px=median_px, seed=params.seed, max_ray_gap=params.max_ray_gap)
    if params.gsd is not None:
        gsd, gsd_source = float(params.gsd), "--gsd"
    elif "gsd_m" in scene:
        gsd, gsd_source = scene_number(scene, scene_path, "gsd_m"), "scene"
    else:
        gsd, gsd_source = float(estimated_gsd), (
            "reference spacing" if route == "disparity-projective" else "estimated")
    interpolated = result.interpolated.astype(np.float32)
    summary: dict[str, Any] = {
        "route": route,
        "target": target_name,
        "shape": list(result.dem.shape),
        "gsd_m": gsd,
        "gsd_source": gsd_source,
        "median_px": median_px,
        "height_min_m": float(result.dem.min()),
        "height_max_m": float(result.dem.max()),
        "interpolated_fraction": float(interpolated.mean()),
        "measured_cells": int(np.count_nonzero(interpolated == 0)),
        "interpolated_cells": int(np.count_nonzero(interpolated)),
        **extra,
        **result.report,
    }
    log.info("DEM %d×%d of %s (%s), GSD %.4g m, %.1f %% measured, heights %.3g … %.3g m",
             result.dem.shape[1], result.dem.shape[0], target_name, route, gsd,
             100 * result.report["measured_fraction"], summary["height_min_m"],
             summary["height_max_m"])
    if dense:
        from demtool.dem.run_dense import log_sources

        log_sources(log, result.report, result.dem.size)
    elif points_path is not None and result.report["measured_fraction"] < SPARSE_MEASURED:
        log.warning("%.1f %% of the DEM is interpolated: %d cells measured (%d bundle points "
                    "in the target), the heights between them are the gap filling's; for "
                    "measured detail add --dense DISPARITY RECTIFY, a pair of the block "
                    "matched by rectify and sgm",
                    100 * summary["interpolated_fraction"], summary["measured_cells"],
                    result.report["points_in_target"])
    tags = prov.tags(frame=f"image:{target_name}", dem_route=route, gsd_m=gsd,
                     units="metres, positive toward the camera", target=target_name,
                     **({"distance_m": extra["distance_m"]} if extra.get("distance_m") else {}))
    transform = dio.image_frame_transform(gsd)
    data = np.stack([result.dem, interpolated]) if mask_band else result.dem
    band_names = ["height", "interpolated"] if mask_band else ["height"]
    outputs = [Path(out)]
    with run.transaction():
        dio.write_raster(out, data, transform=transform, tags=tags, band_names=band_names)
        if mask_path is not None:
            dio.write_raster(mask_path, interpolated, transform=transform,
                             tags=prov.tags(frame=f"image:{target_name}",
                                            meaning="1 = interpolated, 0 = measured"),
                             band_names=["interpolated"])
            outputs.append(Path(mask_path))
        prov.write_sidecar(out, summary, outputs=outputs)
    return summary


def _tile_options(params: DemParams) -> bool:
    return bool(params.tile_size or params.scheduler or params.dry_run)


def _dem_tiled(run: StageRun, params: DemParams, out, *, disparity_path, rectify_path,
               cameras_path, scene: dict, scene_path, mask_path) -> dict | None:
    """The calibrated disparity route in tiles (:mod:`demtool.dem.tiled`); None when the
    target fits in one tile (the untiled path then runs); the other routes refuse the
    tile options (the map-projected route has its own, :mod:`demtool.dem.tiled_map`)."""
    from demtool.dem.tiled import dem_tiled
    from demtool.errors import ParameterError
    from demtool.tiling import wants_tiles

    if disparity_path is None or cameras_path is None:
        raise ParameterError("--tile-size/--scheduler/--dry-run: only the calibrated "
                             "disparity route (--disparity with --cameras) runs in tiles")
    pair = _tiled_pair(disparity_path, rectify_path, cameras_path, params.target)
    camera = pair.left_camera if pair.side == "left" else pair.right_camera
    if not wants_tiles(camera.height, camera.width, params):
        return None
    if params.gsd is not None:
        gsd, source = float(params.gsd), "--gsd"
    elif "gsd_m" in scene:
        gsd, source = scene_number(scene, scene_path, "gsd_m"), "scene"
    else:
        gsd, source = None, "estimated"
    result = dem_tiled(run, params, out, pair, mask_path=mask_path, gsd=gsd, gsd_source=source)
    return {"dry_run": result.dry_run} if result.dry_run is not None else result.summary
