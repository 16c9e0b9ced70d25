"""`demtool dem`: dense DEM in the target image frame from bundle points or a disparity."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import click

from demtool import option_types as ot
from demtool import options as opt
from demtool.cli import STAGES

HELP = STAGES["dem"] + """

Two forms.  From bundle points (BAM route):
`demtool dem --points bundle.npz [--distance D | --scene scene.json] --out dem.tif`
projects the points into the target camera; heights come from eq. 2 of the NavCam
study (depth offset (z/mean(z) - 1)·D, negated) or, for an aligned bundle, are metric.
From a disparity map (SIAM route):
`demtool dem --disparity disparity.tif --rectify rectify.npz (--reference REF.tif |
--cameras cameras.npz) --out dem.tif` maps disparities back through the inverse
rectification and either fits a robust 3-D projective transformation to the
reference DEM (on the target grid) or triangulates with the known cameras.

Both routes remove outliers with a local median test, resample onto the target
image's pixel grid, fill the gaps with D'Errico's spring-metaphor interpolation and
optionally median-filter.  OUT is in the target image frame (frame=image:<target>),
pixel spacing = GSD (--gsd, scene.json gsd_m, the reference's spacing, or estimated
as distance / focal length), heights in metres positive toward the camera.
"""


@click.command(name="dem", help=HELP)
@click.option("--points", type=click.Path(dir_okay=False),
              help="bundle.npz from `demtool bundle` (BAM route).")
@click.option("--disparity", type=click.Path(dir_okay=False),
              help="Disparity GeoTIFF in the left rectified frame (SIAM route).")
@click.option("--rectify", type=click.Path(dir_okay=False),
              help="rectify.npz of the pair (with --disparity).")
@click.option("--reference", type=click.Path(dir_okay=False),
              help="Reference DEM on the target grid (e.g. the BAM DEM): uncalibrated "
                   "projective fit.")
@click.option("--cameras", type=click.Path(dir_okay=False),
              help="cameras.npz with the pair's cameras: calibrated triangulation.")
@click.option("--target", help="Target view name (default: the bundle's target, or the "
                               "left image of the pair).")
@click.option("--distance", type=ot.FloatRange(min=0.0, min_open=True),
              help="Spacecraft-surface distance D, metres (eq. 2; unaligned bundles).")
@click.option("--scene", type=click.Path(dir_okay=False),
              help="scene.json with distance_m and gsd_m (metadata from synth).")
@click.option("--gsd", type=ot.FloatRange(min=0.0, min_open=True),
              help="Pixel spacing of the output, metres (default: from metadata or "
                   "estimated).")
@click.option("--median", type=ot.IntRange(min=0), default=0,
              show_default=True, help="Median filter after filling, odd size in px (0 = off).")
@click.option("--outlier-neighbours", type=ot.IntRange(min=3), default=16,
              show_default=True, help="Neighbours of the local median outlier test.")
@click.option("--outlier-threshold", type=ot.NON_NEGATIVE, default=3.0, show_default=True,
              help="Outlier threshold in local NMADs (0 = no outlier removal).")
@click.option("--interpolated-mask", type=click.Path(dir_okay=False),
              help="Also write a raster: 1 where interpolated, 0 where measured.")
@click.option("--mask-band", is_flag=True,
              help="Write the interpolation mask as a second band of OUT.")
@opt.seed()
@opt.out_file("Output DEM GeoTIFF.")
@click.pass_context
def command(ctx: click.Context, points: str | None, disparity: str | None,
            rectify: str | None, reference: str | None, cameras: str | None,
            target: str | None, distance: float | None, scene: str | None,
            gsd: float | None, median: int, outlier_neighbours: int,
            outlier_threshold: float, interpolated_mask: str | None, mask_band: bool,
            seed: int, out: str) -> None:
    points_path, disparity_path, rectify_path = points, disparity, rectify
    reference_path, cameras_path, median_px = reference, cameras, median
    if (points_path is None) == (disparity_path is None):
        raise click.BadParameter("give exactly one of --points or --disparity",
                                 param_hint="--points/--disparity")
    if disparity_path is not None:
        if rectify_path is None:
            raise click.BadParameter("--disparity needs --rectify", param_hint="--rectify")
        if (reference_path is None) == (cameras_path is None):
            raise click.BadParameter("--disparity needs exactly one of --reference "
                                     "(projective fit) or --cameras (triangulation)",
                                     param_hint="--reference/--cameras")
    elif rectify_path or reference_path or cameras_path:
        raise click.BadParameter("--rectify, --reference and --cameras belong to the "
                                 "--disparity form", param_hint="--points")
    if median_px > 1 and median_px % 2 == 0:
        raise click.BadParameter(f"must be odd, got {median_px}", param_hint="--median")
    run_dem(out, points_path=points_path, disparity_path=disparity_path,
            rectify_path=rectify_path, reference_path=reference_path,
            cameras_path=cameras_path, target=target, distance_m=distance,
            scene_path=scene, gsd_m=gsd, median_px=median_px,
            outlier_neighbours=outlier_neighbours, outlier_threshold=outlier_threshold,
            mask_path=interpolated_mask, mask_band=mask_band, seed=seed,
            params=opt.resolved_params(ctx))


def _scene_metadata(scene_path: str | os.PathLike | None) -> dict[str, Any]:
    """scene.json content ({} without one); InputError if it is not a JSON object."""
    from demtool import io as dio
    from demtool.errors import InputError

    if scene_path is None:
        return {}
    content = dio.read_json(scene_path, "scene file")
    if not isinstance(content, dict):
        raise InputError(f"{scene_path}: scene file is not a JSON object")
    return content


def _positive(value: Any, path: Any, key: str) -> float:
    """A metadata value as a positive float; InputError naming the file and key."""
    from demtool.errors import InputError

    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not number > 0:
        raise InputError(f"{path}: '{key}' must be a positive number, got {value!r}")
    return number


def _points_route(points_path: str | os.PathLike, *, target: str | None,
                  distance_m: float | None, scene: dict[str, Any],
                  scene_path: str | os.PathLike | None, outliers: Any,
                  median_px: int) -> tuple[Any, str, str, float, dict[str, Any]]:
    """BAM route: (DemResult, target name, route tag, estimated GSD, extra summary)."""
    import numpy as np

    from demtool import dem as core
    from demtool import io as dio
    from demtool.camera import cameras_from_arrays
    from demtool.errors import InputError, ParameterError

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
        if "distance_m" in scene:
            distance_m = _positive(scene["distance_m"], scene_path, "distance_m")
        else:
            raise ParameterError("the bundle is not aligned: give the spacecraft-surface "
                                 "distance with --distance or --scene scene.json")
    camera = cameras[target_name]
    result = core.dem_from_points(bundle["points"], camera, aligned=aligned,
                                  distance_m=distance_m, distortion=distortion,
                                  outliers=outliers, median_px=median_px)
    estimated_gsd = core.estimate_gsd(camera, aligned=aligned,
                                      depth=np.array([result.report["median_depth"]]),
                                      distance_m=distance_m)
    route = "points-metric" if aligned else "points-eq2"
    return result, target_name, route, estimated_gsd, {"distance_m": distance_m}


def _disparity_route(disparity_path: str | os.PathLike, rectify_path: str | os.PathLike, *,
                     reference_path: str | os.PathLike | None,
                     cameras_path: str | os.PathLike | None, target: str | None,
                     outliers: Any, median_px: int,
                     seed: int) -> tuple[Any, str, str, float, dict[str, Any]]:
    """SIAM routes: (DemResult, target name, route tag, estimated GSD, extra summary)."""
    from demtool import dem as core
    from demtool import io as dio
    from demtool.camera import cameras_from_arrays
    from demtool.errors import InputError

    rectification = dio.read_npz(rectify_path, "rectification")
    disparity = dio.read_raster(disparity_path, what="disparity")
    width_rect, height_rect = (int(v) for v in rectification["size_rect"])
    if disparity.data.shape != (height_rect, width_rect):
        raise InputError(f"{disparity_path}: disparity is {disparity.data.shape[1]}×"
                         f"{disparity.data.shape[0]} px but {rectify_path} has a "
                         f"{width_rect}×{height_rect} rectified canvas")
    left_name = str(rectification["left_name"])
    right_name = str(rectification["right_name"])
    target_name = target or left_name
    if target_name not in (left_name, right_name):
        raise InputError(f"{rectify_path}: target {target_name} is neither the left "
                         f"({left_name}) nor the right ({right_name}) image of the pair")
    side = "left" if target_name == left_name else "right"
    width, height = (int(v) for v in rectification[f"size_{side}"])
    H_left, H_right = rectification["H_left"], rectification["H_right"]
    if cameras_path is not None:
        cameras = cameras_from_arrays(dio.read_npz(cameras_path, "cameras"))
        missing = [n for n in (left_name, right_name) if n not in cameras]
        if missing:
            raise InputError(f"{cameras_path}: no camera for {', '.join(missing)}")
        for name, side_name in ((left_name, "left"), (right_name, "right")):
            size = tuple(int(v) for v in rectification[f"size_{side_name}"])
            if (cameras[name].width, cameras[name].height) != size:
                raise InputError(f"{cameras_path}: camera {name} is {cameras[name].width}×"
                                 f"{cameras[name].height} px but {rectify_path} says the "
                                 f"{side_name} image is {size[0]}×{size[1]}")
        result = core.dem_from_disparity_calibrated(
            disparity.data, H_left, H_right, cameras[left_name], cameras[right_name],
            target=side, outliers=outliers, median_px=median_px)
        target_camera = cameras[target_name]
        estimated_gsd = result.report["median_depth_m"] / target_camera.focal_px
        return result, target_name, "disparity-calibrated", estimated_gsd, {}
    reference = dio.read_raster(reference_path, what="reference DEM")
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


def run_dem(out: str | os.PathLike, *, points_path: PathLike = None,
            disparity_path: PathLike = None, rectify_path: PathLike = None,
            reference_path: PathLike = None, cameras_path: PathLike = None,
            target: str | None = None, distance_m: float | None = None,
            scene_path: PathLike = None, gsd_m: float | None = None, median_px: int = 0,
            outlier_neighbours: int = 16, outlier_threshold: float = 3.0,
            mask_path: PathLike = None, mask_band: bool = False, seed: int = 0,
            params: dict | None = None) -> dict:
    """Run the dem stage: read the inputs, build the DEM, write it with its sidecar.

    Returns the sidecar summary.
    """
    import numpy as np

    from demtool import dem as core
    from demtool import io as dio
    from demtool.logs import get_logger
    from demtool.provenance import Provenance

    log = get_logger("dem")
    inputs = [p for p in (points_path, disparity_path, rectify_path, reference_path,
                          cameras_path, scene_path) if p is not None]
    for path in inputs:
        dio.require_file(path, "input file")
    prov = Provenance("dem", params or {}, inputs)
    scene = _scene_metadata(scene_path)
    outliers = core.OutlierOptions(neighbours=outlier_neighbours, threshold=outlier_threshold)
    if points_path is not None:
        result, target_name, route, estimated_gsd, extra = _points_route(
            points_path, target=target, distance_m=distance_m, scene=scene,
            scene_path=scene_path, outliers=outliers, median_px=median_px)
    else:
        result, target_name, route, estimated_gsd, extra = _disparity_route(
            disparity_path, rectify_path, reference_path=reference_path,
            cameras_path=cameras_path, target=target, outliers=outliers,
            median_px=median_px, seed=seed)
    if gsd_m is not None:
        gsd, gsd_source = float(gsd_m), "--gsd"
    elif "gsd_m" in scene:
        gsd, gsd_source = _positive(scene["gsd_m"], scene_path, "gsd_m"), "scene"
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
        **extra,
        **result.report,
    }
    log.info("DEM %d×%d of %s (%s), GSD %.4g m, %.1f %% measured, heights %.3g … %.3g m",
             result.dem.shape[1], result.dem.shape[0], target_name, route, gsd,
             100 * result.report["measured_fraction"], summary["height_min_m"],
             summary["height_max_m"])
    tags = prov.tags(frame=f"image:{target_name}", dem_route=route, gsd_m=gsd,
                     units="metres, positive toward the camera", target=target_name,
                     **({"distance_m": extra["distance_m"]} if extra.get("distance_m") else {}))
    transform = dio.image_frame_transform(gsd)
    data = np.stack([result.dem, interpolated]) if mask_band else result.dem
    band_names = ["height", "interpolated"] if mask_band else ["height"]
    outputs = [Path(out)]
    with dio.output_transaction():
        dio.write_raster(out, data, transform=transform, tags=tags, band_names=band_names)
        if mask_path is not None:
            dio.write_raster(mask_path, interpolated, transform=transform,
                             tags=prov.tags(frame=f"image:{target_name}",
                                            meaning="1 = interpolated, 0 = measured"),
                             band_names=["interpolated"])
            outputs.append(Path(mask_path))
        prov.write_sidecar(out, summary, outputs=outputs)
    return summary
