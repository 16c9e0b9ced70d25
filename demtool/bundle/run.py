"""Runner of ``demtool bundle``: structure from motion and bundle adjustment of any block
of images (a ``selection.json``, image paths, or a list file) with pycolmap, written as
``bundle.npz``."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.bundle.inputs import Block
    from demtool.bundle.params import BundleParams


def read_block(inputs: Sequence[str | os.PathLike],
               image_list: str | os.PathLike | None = None) -> Block:
    """The block of one selection.json, of image paths, or of a list file.

    See :mod:`demtool.bundle.inputs`: selection and list paths are resolved against the
    file's own folder.
    """
    from demtool import bundle as core
    from demtool import io as dio
    from demtool.errors import ParameterError

    if image_list is not None:
        if inputs:
            raise ParameterError("give a selection.json or image files, or --images LIST, "
                                 "not both")
        return core.read_image_list(image_list)
    if not inputs:
        raise ParameterError("give a selection.json or image files, or --images LIST")
    if len(inputs) == 1 and Path(inputs[0]).suffix.lower() == ".json":
        return core.read_selection(dio.require_file(inputs[0], "selection file"))
    if any(Path(p).suffix.lower() == ".json" for p in inputs):
        raise ParameterError("a selection.json comes alone, not with image files")
    if len(inputs) == 1:
        dio.require_file(inputs[0], "image")
    return core.block_from_paths([str(p) for p in inputs])


def run_bundle(inputs: Sequence[str | os.PathLike] | str | os.PathLike,
               out: str | os.PathLike, params: BundleParams | None = None, *,
               image_list: str | os.PathLike | None = None,
               colmap_dir: str | os.PathLike | None = None,
               cameras_path: str | os.PathLike | None = None,
               align_path: str | os.PathLike | None = None,
               sensors: Sequence[str | os.PathLike] | None = None,
               adjusted_dir: str | os.PathLike | None = None,
               reference_dem: str | os.PathLike | None = None, verbose: bool = False,
               resolved: dict | None = None,
               control_network: str | os.PathLike | None = None,
               adjusted_network: str | os.PathLike | None = None,
               serials: str | os.PathLike | None = None,
               reference_points: str | os.PathLike | None = None) -> dict:
    """Run the bundle stage: read the block, adjust it, write bundle.npz and its sidecar.

    ``inputs`` is one selection.json or image paths (or empty with ``image_list``);
    ``cameras_path`` gives known intrinsics (not with ``params.focal_px``),
    ``align_path`` known camera centres to align the model to; ``reference_dem`` (with
    sensor models) a DEM tying the tie points' heights; ``colmap_dir`` also
    receives the COLMAP model.  ``verbose`` shows COLMAP's own log.  Returns the sidecar
    summary.
    """
    import time

    from demtool import bundle as core
    from demtool import io as dio
    from demtool.bundle.params import BundleParams
    from demtool.errors import InputError
    from demtool.sensors.pinhole import cameras_from_arrays

    params = params or BundleParams()
    params.check()
    started = time.perf_counter()
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if control_network is not None:  # sensor models on an ISIS control network
        from demtool.bundle.run_network import check_network_options, run_bundle_network

        check_network_options(inputs, sensors, image_list, {
            "INPUTS": bool(inputs), "--images": image_list, "--colmap-dir": colmap_dir,
            "--cameras": cameras_path, "--align-cameras": align_path,
            "--reference-dem": reference_dem})
        return run_bundle_network(sensors, control_network, out, params,
                                  adjusted_dir=adjusted_dir,
                                  adjusted_network=adjusted_network, serials=serials,
                                  reference_points=reference_points,
                                  resolved=resolved, started=started)
    for option, value in (("--adjusted-network", adjusted_network), ("--serials", serials),
                          ("--reference-points", reference_points)):
        if value is not None:
            from demtool.errors import ParameterError

            raise ParameterError(f"{option} needs --control-network")
    block = read_block(list(inputs), image_list)
    sensor_paths = sensor_models_of(block, sensors)
    if sensor_paths is not None:
        return run_bundle_with_sensors(block, sensor_paths, out, params, image_list=image_list,
                                       adjusted_dir=adjusted_dir, inputs=list(inputs),
                                       reference_dem=reference_dem,
                                       resolved=resolved, started=started,
                                       other_options={"--colmap-dir": colmap_dir,
                                                      "--cameras": cameras_path,
                                                      "--align-cameras": align_path})
    if params.matcher == "spatial":
        from demtool.errors import ParameterError

        raise ParameterError("--matcher spatial needs sensor models (--sensors, or ISIS "
                             "cubes with SPICE as the images)")
    if adjusted_dir is not None or reference_dem is not None:
        from demtool.errors import ParameterError

        option = "--adjusted-dir" if adjusted_dir is not None else "--reference-dem"
        raise ParameterError(f"{option} needs sensor models (--sensors, or ISIS cubes "
                             "with SPICE as the images)")
    known_cameras = None
    if cameras_path is not None:
        known_cameras = cameras_from_arrays(dio.read_npz(cameras_path, "cameras"))
        missing = [n for n in block.names if n not in known_cameras]
        if missing:
            raise InputError(f"{cameras_path}: no camera for {', '.join(missing)}")
    known_centres = None
    if align_path is not None:
        known_centres = {n: c.center for n, c in
                         cameras_from_arrays(dio.read_npz(align_path, "cameras")).items()}
    sources = {"--images": image_list} if image_list is not None else \
        {"SELECTION": inputs[0]} if block.target is not None else {}
    run = StageRun("bundle", params, resolved=resolved,
                   inputs={**sources, "images": list(block.paths),
                           "--cameras": cameras_path, "--align-cameras": align_path},
                   outputs={"--out": out, "sidecar": sidecar_path(out)},
                   folders={"--colmap-dir": colmap_dir})
    log, prov = run.log, run.provenance

    def images():
        for name, path in zip(block.names, block.paths, strict=True):
            data = dio.read_image(path, what=f"image {name}").data
            if known_cameras is not None:
                camera = known_cameras[name]
                if (camera.height, camera.width) != data.shape:
                    raise InputError(f"{cameras_path}: camera {name} is {camera.width}×"
                                     f"{camera.height} px but {path} is {data.shape[1]}×"
                                     f"{data.shape[0]}")
            yield name, data

    focal_px = params.known_focal_px()

    def intrinsics(shapes):
        if focal_px is None and known_cameras is None:
            return None
        if focal_px is not None:
            for shape in set(shapes.values()):
                core.check_focal_px(focal_px, shape, known_decisions(params, None)["f"]
                                    ["source"])
        return core.known_intrinsics(
            shapes, focal_px=focal_px, refine=params.refine_intrinsics,
            matrices=None if known_cameras is None else
            {n: known_cameras[n].K for n in block.names})

    core.set_colmap_verbosity(verbose)
    known = focal_px is not None or known_cameras is not None
    options = core.SfmOptions(
        shared_camera=params.shared_camera,
        camera_model=params.camera_model or ("PINHOLE" if known else "SIMPLE_RADIAL"),
        matcher=params.matcher,
        max_features=params.max_features or core.SfmOptions.max_features,
        features=params.features,
        seed=params.seed, workers=params.workers, reproducible=params.reproducible)
    adjusted = core.adjust_block(images(), options, target=block.target, intrinsics=intrinsics,
                                 self_calibration=params.self_calibrate,
                                 focal_only=focal_px is not None,
                                 keep_model=colmap_dir is not None)
    result, summary = adjusted.result, adjusted.summary
    summary["source"] = block.source
    if known and "decisions" not in summary["intrinsics"]:
        summary["intrinsics"]["decisions"] = known_decisions(params, cameras_path)
    elif known:
        summary["intrinsics"]["decisions"]["f"].update(known_decisions(params, None)["f"])
    if known_centres is not None:
        result, alignment = core.align_to_centres(result, known_centres)
        log.info("aligned to %d known camera centres: scale %.6g, centre RMS %.3g m",
                 alignment["centres_used"], alignment["scale"], alignment["centre_rms_m"])
        summary["alignment"] = alignment
    summary["aligned"] = result.aligned
    log.info("registered %d/%d images, %d points, reprojection error mean %.3f px, "
             "95th percentile %.3f px; intrinsics %s, refined %s",
             summary["registered_count"], summary["image_count"], summary["points"],
             summary["mean_reprojection_error_px"], summary["p95_reprojection_error_px"],
             summary["intrinsics"]["mode"], ", ".join(summary["intrinsics"]["refined"])
             or "none")
    for name, row in summary["images"].items():
        log.info("  %-20s %6d observations, residual mean %.3f px", name,
                 row["observations"], row["mean_residual_px"])
    if summary["not_registered"]:
        log.warning("not registered: %s", ", ".join(summary["not_registered"]))
    with run.transaction():
        dio.write_npz(out, "bundle", result.to_arrays())
        outputs = [Path(out)]
        for file_name, content in adjusted.model_files.items():
            final = Path(colmap_dir) / file_name
            with dio.atomic_path(final) as temporary:
                temporary.write_bytes(content)
            outputs.append(final)
        summary["time_s"] = round(time.perf_counter() - started, 2)
        prov.write_sidecar(out, summary, outputs=outputs)
    return summary


#: a camera moved farther than this many σ of its priors gets a warning
FAR_MOVE_SIGMAS = 3.0


def warn_far_moves(summary: dict, params, log, *, reference: bool) -> None:
    """One warning per image moved more than :data:`FAR_MOVE_SIGMAS` σ of its priors,
    naming the σ to raise (the priors', or the reference DEM's that pulls the block)."""
    for name, row in summary["images"].items():
        far = []
        if row["position_change_prior_sigmas"] > FAR_MOVE_SIGMAS:
            far.append(f"position by {row['position_change_m']:.1f} m = "
                       f"{row['position_change_prior_sigmas']:.1f} sigma "
                       f"(--position-sigma {params.position_sigma:g} m)")
        if row["pointing_change_prior_sigmas"] > FAR_MOVE_SIGMAS:
            far.append(f"pointing by {row['pointing_change_mrad']:.3g} mrad = "
                       f"{row['pointing_change_prior_sigmas']:.1f} sigma "
                       f"(--pointing-sigma {params.pointing_sigma:g} mrad)")
        if far:
            options = " or ".join(o for o, moved in
                                  (("--position-sigma", "position" in far[0]),
                                   ("--pointing-sigma", "pointing" in far[-1])) if moved)
            log.warning("%s moved %s, more than %g sigma of its priors: raise %s if the "
                        "priors are that far off%s", name, " and ".join(far),
                        FAR_MOVE_SIGMAS, options,
                        ", or --reference-dem-sigma if the reference DEM pulls the block"
                        if reference else "")


def known_decisions(params, cameras_path) -> dict:
    """The sidecar's per-parameter record of user-given intrinsics."""
    if cameras_path is not None:
        source = f"--cameras {cameras_path}"
    elif params.focal_mm is not None:
        source = f"--focal-mm {params.focal_mm:g} / --pixel-mm {params.pixel_mm:g}"
    else:
        source = f"--focal-px {params.focal_px:g}"
    f_status = "given, refined" if params.refine_intrinsics else "given"
    pp = "given" if cameras_path is not None else "image centre (given focal length only)"
    return {"f": {"status": f_status, "source": source,
                  **({"value": params.known_focal_px()} if cameras_path is None else {})},
            "cx": {"status": pp}, "cy": {"status": pp}}


def sensor_models_of(block: Block, sensors: Sequence[str | os.PathLike] | None
                     ) -> list[Path] | None:
    """The sensor model file of each image: ``--sensors`` (one per image, same order), or
    the images themselves when every one is an ISIS cube; None without models."""
    from demtool.errors import ParameterError

    if sensors:
        if len(sensors) != len(block.paths):
            raise ParameterError(f"--sensors: {len(sensors)} sensor model(s) for "
                                 f"{len(block.paths)} images; give one per image, in the "
                                 "same order")
        return [Path(p) for p in sensors]
    if all(p.suffix.lower() == ".cub" for p in block.paths):
        return list(block.paths)
    return None


def _adjusted_name(sensor: Path, kind: str) -> str:
    return sensor.stem + (".tsai" if kind == "tsai" else ".json")


def run_bundle_with_sensors(block: Block, sensor_paths: Sequence[Path], out, params, *,
                            image_list=None, adjusted_dir=None, inputs=(), resolved=None,
                            started: float = 0.0, other_options=None,
                            reference_dem=None) -> dict:
    """The ``--sensors`` route of :func:`run_bundle`: tie points, pose-prior bundle
    adjustment of the models in the body-fixed frame, ``bundle.npz`` (tie points and
    local pinholes, metric) and the adjusted models in their own formats."""
    import json
    import time

    from demtool import io as dio
    from demtool.bundle import writeback
    from demtool.bundle.sensorblock import adjust_sensor_block
    from demtool.errors import InputError, ParameterError
    from demtool.sensors import read_sensor
    from demtool.sensors.readers import _sniff

    for option, value in {**(other_options or {}), "--focal-px": params.focal_px,
                          "--focal-mm": params.focal_mm}.items():
        if value is not None:
            raise ParameterError(f"{option} does not apply with sensor models (--sensors or "
                                 "cubes)")
    kinds = []
    for path in sensor_paths:
        dio.require_file(path, "sensor model")
        kind = _sniff(path)
        if kind == "npz":
            raise InputError(f"{path}: a cameras/bundle NPZ is not a sensor model with a "
                             "pose prior; give ISDs, ISIS cubes or .tsai files")
        kinds.append(kind)
    if adjusted_dir is not None:
        names = [_adjusted_name(p, k) for p, k in zip(sensor_paths, kinds, strict=True)]
        if len(set(names)) != len(names):
            raise ParameterError("--adjusted-dir: two sensor models share a file stem; "
                                 "their adjusted models would overwrite each other")
        adjusted_paths = [Path(adjusted_dir) / n for n in names]
        given = {p.resolve() for p in sensor_paths}
        for final in adjusted_paths:
            if final.resolve() in given:
                raise ParameterError(f"--adjusted-dir: {final} would overwrite the input "
                                     "sensor model; choose another folder")
    else:
        adjusted_paths = []
    sources = {"--images": image_list} if image_list is not None else \
        {"SELECTION": inputs[0]} if block.target is not None else {}
    run = StageRun("bundle", params, resolved=resolved,
                   inputs={**sources, "images": list(block.paths),
                           "--sensors": list(sensor_paths), "--reference-dem": reference_dem},
                   outputs={"--out": out, "adjusted models": adjusted_paths or None},
                   folders={"--adjusted-dir": adjusted_dir})
    log, prov = run.log, run.provenance
    models = [read_sensor(p) for p in sensor_paths]
    from demtool.bundle.block_checks import check_block

    check_block(models, sensor_paths, list(block.names), list(block.paths))
    radii = next((m.radii for m in models if m.radii is not None), None)
    for k, (path, kind) in enumerate(zip(sensor_paths, kinds, strict=True)):
        if kind == "tsai":
            models[k] = read_sensor(path, radii=radii)
    images = []
    for name, path, model, sensor in zip(block.names, block.paths, models, sensor_paths,
                                         strict=True):
        data = dio.read_image(path, what=f"image {name}").data
        if not model.lines and hasattr(model, "width"):  # a .tsai carries no image size
            import dataclasses

            model = dataclasses.replace(model, width=data.shape[1], height=data.shape[0])
            models[len(images)] = model
        if model.lines and model.samples and (model.lines, model.samples) != data.shape:
            raise InputError(f"{sensor}: sensor model is {model.samples}x{model.lines} px but "
                             f"image {path} is {data.shape[1]}x{data.shape[0]}; give the "
                             "model of that image")
        images.append(data)
    surface = None
    if reference_dem is not None:
        from demtool.bundle.run_reference import read_reference_surface

        surface = read_reference_surface(reference_dem, models, sensor_paths,
                                         sigma=params.reference_dem_sigma)
    if params.matcher == "spatial" and any(m.radii is None for m in models):
        raise ParameterError("--matcher spatial needs the body's radii; .tsai files carry "
                             "none: give an ISD or cube too, or another --matcher")
    pairing = params.matcher if params.matcher in ("spatial", "sequential", "exhaustive") \
        else "exhaustive" if len(models) <= 100 else "sequential"
    adjusted = adjust_sensor_block(list(block.names), images, models, pairing=pairing,
                                   position_sigma=params.position_sigma,
                                   pointing_sigma=params.pointing_sigma,
                                   max_features=params.max_features, seed=params.seed,
                                   surface=surface, refine_ties=params.refine_ties,
                                   register_to_dem=params.register_to_dem)
    summary = adjusted.summary
    summary["source"] = block.source
    summary["aligned"] = True
    summary["intrinsics"] = {"mode": "sensor models", "refined": []}
    log.info("%d images, %d tie points, %d observations; reprojection error RMS %.3f px "
             "before, mean %.3f px after", len(block.names), summary["points"],
             summary["observations"], summary["initial_rms_reprojection_error_px"],
             summary["mean_reprojection_error_px"])
    for name, row in summary["images"].items():
        log.info("  %-20s %6d observations, residual mean %.3f px, position %+.2f m "
                 "(%.2f sigma), pointing %.4f mrad (%.2f sigma)", name, row["observations"],
                 row["mean_residual_px"] or float("nan"), row["position_change_m"],
                 row["position_change_prior_sigmas"], row["pointing_change_mrad"],
                 row["pointing_change_prior_sigmas"])
    warn_far_moves(summary, params, log, reference=reference_dem is not None)
    if "reference_dem" in summary:
        dem = summary["reference_dem"]
        log.info("reference DEM: %d tie points on it, height residual median %.2f m, "
                 "RMS %.2f m (sigma %.2f m, post^2/8 x curvature and %.2f x its %.0f m "
                 "posts x the local slope: median %.1f m, 90th percentile %.1f m)",
                 dem["points_on_dem"], dem["height_residual_median_m"] or float("nan"),
                 dem["height_residual_rms_m"] or float("nan"), dem["sigma_m"],
                 dem["interpolation_factor"], dem["post_spacing_m"],
                 dem["tie_point_sigma_median_m"],
                 dem["tie_point_sigma_p90_m"])
        if not dem["points_on_dem"]:
            log.warning("no tie point lies on the reference DEM's data: the block's datum "
                        "is the priors' alone")
    with dio.output_transaction():
        dio.write_npz(out, "bundle", adjusted.result.to_arrays())
        outputs = [Path(out)]
        written = {}
        for path, kind, offset, final, name in zip(sensor_paths, kinds,
                                                   adjusted.adjustment.offsets,
                                                   adjusted_paths or [None] * len(kinds),
                                                   block.names, strict=True):
            if final is None:
                continue
            if kind == "tsai":
                text = writeback.adjust_tsai(path.read_text(encoding="utf-8"), offset,
                                             source=str(path))
            else:
                isd = (json.loads(path.read_text(encoding="utf-8")) if kind == "isd"
                       else writeback.model_isd(read_sensor(path)))
                text = writeback.dumps_isd(writeback.adjust_isd(isd, offset))
            with dio.atomic_path(final) as temporary:
                temporary.write_text(text, encoding="utf-8")
            outputs.append(final)
            written[name] = str(final)
        summary["adjusted_models"] = written
        if not written:
            log.warning("no --adjusted-dir: the adjusted sensor models are not written")
        summary["time_s"] = round(time.perf_counter() - started, 2)
        prov.write_sidecar(out, summary, outputs=outputs)
    return summary
