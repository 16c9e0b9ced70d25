"""`demtool bundle`: structure from motion and bundle adjustment of selected images."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import click

from demtool import option_types as ot
from demtool import options as opt
from demtool.cli import STAGES

HELP = STAGES["bundle"] + """

Reads SELECTION (selection.json from `demtool select`; the target first) and runs
COLMAP through pycolmap: SIFT features, exhaustive or sequential matching with
geometric verification, incremental mapping with bundle adjustment.  By default all
images share one camera whose focal length and radial distortion COLMAP estimates
(SIMPLE_RADIAL while mapping, a second radial term in a final adjustment);
--focal-px or --cameras give known intrinsics (kept fixed unless
--refine-intrinsics).  The largest model is written to OUT (bundle.npz: points,
intensities, track lengths, reprojection errors, cameras, target index) with the
sidecar OUT.json (registered images, points, mean and 95th-percentile reprojection
error).  --align-cameras maps the model onto known camera centres (similarity,
Umeyama 1991) so that it is metric, in the world frame.
"""


@click.command(name="bundle", help=HELP)
@opt.input_file("selection")
@opt.out_file("Output bundle.npz.")
@click.option("--colmap-dir", type=click.Path(file_okay=False),
              help="Also write the COLMAP model (binary) into this folder, for COLMAP's GUI.")
@click.option("--focal-px", type=ot.FloatRange(min=0.0, min_open=True),
              help="Known focal length, pixels (principal point at the image centre).")
@click.option("--cameras", type=click.Path(dir_okay=False),
              help="cameras.npz with known intrinsics K of the images (matched by name).")
@click.option("--refine-intrinsics", is_flag=True,
              help="Let bundle adjustment refine known focal lengths (default: fixed).")
@click.option("--shared-camera/--per-image-camera", default=True, show_default=True,
              help="One camera for all images (one instrument) or one per image.")
@click.option("--camera-model", type=click.Choice(["SIMPLE_PINHOLE", "PINHOLE",
                                                   "SIMPLE_RADIAL", "RADIAL"]),
              help="COLMAP camera model (pinhole, optionally with radial distortion); "
                   "default SIMPLE_RADIAL (f, k), or PINHOLE with known intrinsics.")
@click.option("--radial-k2/--no-radial-k2", default=True, show_default=True,
              help="After mapping with SIMPLE_RADIAL, free a second radial term k2 in a "
                   "final global bundle adjustment (RADIAL model).")
@click.option("--matcher", type=click.Choice(["auto", "exhaustive", "sequential"]),
              default="auto", show_default=True,
              help="Pair selection: all pairs, or neighbours in selection order "
                   "(auto: exhaustive up to 100 images).")
@click.option("--max-features", type=ot.IntRange(min=64), default=8192, show_default=True,
              help="SIFT features per image.")
@click.option("--align-cameras", type=click.Path(dir_okay=False),
              help="cameras.npz with known camera centres: align the model to them "
                   "(metric world frame).")
@opt.seed()
@opt.workers()
@click.pass_context
def command(ctx: click.Context, selection: str, out: str, colmap_dir: str | None,
            focal_px: float | None, cameras: str | None, refine_intrinsics: bool,
            shared_camera: bool, camera_model: str | None, radial_k2: bool, matcher: str,
            max_features: int,
            align_cameras: str | None, seed: int, workers: int) -> None:
    if focal_px is not None and cameras is not None:
        raise click.BadParameter("give either --focal-px or --cameras, not both",
                                 param_hint="--focal-px")
    from demtool.cli import AppState

    state = ctx.find_object(AppState)
    verbose = state is not None and state.verbosity > 0
    run_bundle(selection, out, colmap_dir=colmap_dir, focal_px=focal_px,
               cameras_path=cameras, refine_intrinsics=refine_intrinsics,
               shared_camera=shared_camera, camera_model=camera_model, radial_k2=radial_k2,
               matcher=matcher,
               max_features=max_features, align_path=align_cameras, seed=seed,
               workers=workers, verbose=verbose, params=opt.resolved_params(ctx))


def _resolve_image_path(path: str, selection_path: Path) -> Path:
    """A selection's image path: as given (relative to the working folder), else
    relative to the selection file's folder."""
    candidate = Path(path)
    if candidate.is_file() or candidate.is_absolute():
        return candidate
    beside = selection_path.parent / candidate
    return beside if beside.is_file() else candidate


def read_selection(path: str | os.PathLike) -> tuple[str, list[tuple[str, Path]]]:
    """Target name and the selected images (name, path) of a selection.json, target first."""
    from demtool import io as dio
    from demtool.errors import InputError

    selection_path = Path(path)
    content = dio.read_json(selection_path, "selection file")
    try:
        target = str(content["target"]["name"])
        entries = [(str(e["name"]), str(e["path"])) for e in content["selected"]]
    except (KeyError, TypeError) as exc:
        raise InputError(f"{selection_path}: not a selection file from `demtool select` "
                         f"(missing {exc})") from None
    names = [name for name, _ in entries]
    if len(set(names)) != len(names):
        raise InputError(f"{selection_path}: selected image names are not unique")
    if target not in names:
        target_path = str(content["target"].get("path", ""))
        entries.insert(0, (target, target_path))
    images = [(name, _resolve_image_path(p, selection_path)) for name, p in entries]
    return target, images


def to_uint8(image: Any) -> Any:
    """An image as 8-bit for COLMAP: unchanged if it already is 8-bit data, else a
    linear stretch between the 0.1 and 99.9 percentiles; NaN becomes 0."""
    import numpy as np

    finite = np.isfinite(image)
    values = image[finite]
    if values.min() >= 0 and values.max() <= 255 and np.all(values == np.round(values)):
        scaled = np.where(finite, image, 0.0)
    else:
        low, high = np.percentile(values, [0.1, 99.9])
        span = max(float(high - low), 1e-12)
        scaled = np.where(finite, (image - low) / span * 255.0, 0.0)
    return np.clip(np.round(scaled), 0, 255).astype(np.uint8)


def run_bundle(selection: str | os.PathLike, out: str | os.PathLike, *,
               colmap_dir: str | os.PathLike | None = None, focal_px: float | None = None,
               cameras_path: str | os.PathLike | None = None, refine_intrinsics: bool = False,
               shared_camera: bool = True, camera_model: str | None = None,
               radial_k2: bool = True,
               matcher: str = "auto", max_features: int = 8192,
               align_path: str | os.PathLike | None = None, seed: int = 0, workers: int = 0,
               verbose: bool = False, params: dict | None = None) -> dict:
    """Run the bundle stage: read the selection, run SfM, write bundle.npz and sidecar.

    Returns the sidecar summary.
    """
    import shutil
    import tempfile
    import time
    from dataclasses import replace

    import cv2
    import numpy as np

    from demtool import bundle as core
    from demtool import io as dio
    from demtool.camera import cameras_from_arrays
    from demtool.errors import InputError, ProcessingError
    from demtool.logs import get_logger
    from demtool.provenance import Provenance

    log = get_logger("bundle")
    started = time.perf_counter()
    selection_path = dio.require_file(selection, "selection file")
    target, images = read_selection(selection_path)
    if len(images) < 2:
        raise InputError(f"{selection_path}: bundle adjustment needs at least 2 images, "
                         f"the selection has {len(images)} ({', '.join(n for n, _ in images)})")
    for name, path in images:
        dio.require_file(path, f"image {name}")
    known_cameras = None
    if cameras_path is not None:
        known_cameras = cameras_from_arrays(dio.read_npz(cameras_path, "cameras"))
        missing = [n for n, _ in images if n not in known_cameras]
        if missing:
            raise InputError(f"{cameras_path}: no camera for {', '.join(missing)}")
    known_centres = None
    if align_path is not None:
        known_centres = {n: c.center for n, c in
                         cameras_from_arrays(dio.read_npz(align_path, "cameras")).items()}
    prov = Provenance("bundle", params or {}, [selection_path] + [p for _, p in images]
                      + [p for p in (cameras_path, align_path) if p is not None])

    core.set_colmap_verbosity(verbose)
    with tempfile.TemporaryDirectory(prefix="demtool-bundle-") as scratch:
        scratch_path = Path(scratch)
        image_folder = scratch_path / "images"
        image_folder.mkdir()
        files: dict[str, str] = {}
        intrinsics: dict[str, core.KnownIntrinsics] = {}
        for name, path in images:
            raster = dio.read_image(path, what=f"image {name}")
            file_name = f"{name}.png"
            if not cv2.imwrite(str(image_folder / file_name), to_uint8(raster.data)):
                raise ProcessingError(f"cannot write a scratch copy of {path} for COLMAP")
            files[file_name] = name
            height, width = raster.data.shape
            if focal_px is not None:
                K = np.array([[focal_px, 0, (width - 1) / 2], [0, focal_px, (height - 1) / 2],
                              [0, 0, 1.0]])
                intrinsics[name] = core.KnownIntrinsics(K, refine_intrinsics)
            elif known_cameras is not None:
                camera = known_cameras[name]
                if (camera.width, camera.height) != (width, height):
                    raise InputError(f"{cameras_path}: camera {name} is {camera.width}×"
                                     f"{camera.height} px but {path} is {width}×{height}")
                intrinsics[name] = core.KnownIntrinsics(camera.K, refine_intrinsics)
        options = core.SfmOptions(
            shared_camera=shared_camera,
            camera_model=camera_model or ("PINHOLE" if intrinsics else "SIMPLE_RADIAL"),
            intrinsics=intrinsics or None, matcher=matcher, max_features=max_features,
            seed=seed, workers=workers)
        models = core.run_sfm(image_folder, files, scratch_path, options)
        imposed = False
        if intrinsics and (not models or models[0].num_reg_images() < len(images)):
            log.warning("COLMAP registered %d of %d images with the known intrinsics; "
                        "mapping with free intrinsics and imposing the known ones after",
                        models[0].num_reg_images() if models else 0, len(images))
            free_folder = scratch_path / "free"
            free_folder.mkdir()
            free = core.run_sfm(image_folder, files, free_folder,
                                replace(options, intrinsics=None, camera_model="SIMPLE_RADIAL",
                                        shared_camera=options.shared_camera))
            if free and (not models or free[0].num_reg_images() > models[0].num_reg_images()):
                core.set_colmap_verbosity(verbose)
                core.impose_intrinsics(free[0], intrinsics, files, workers=workers)
                models, imposed = free, True
        selected_names = [n for n, _ in images]
        if not models or models[0].num_reg_images() < 2:
            registered = ([files[models[0].image(i).name] for i in models[0].reg_image_ids()]
                          if models else [])
            raise ProcessingError(
                f"reconstruction failed: {len(registered)} of {len(images)} images registered "
                f"({', '.join(registered) or 'none'}); the images may not overlap enough or "
                f"lack texture (try more --max-features)")
        model = models[0]
        if radial_k2 and not intrinsics:
            core.set_colmap_verbosity(verbose)
            if core.refine_second_radial_term(model, workers=workers):
                log.info("final bundle adjustment with a second radial term (RADIAL)")
        result = core.reconstruction_to_result(model, files, selected_names, target)
        alignment = None
        if known_centres is not None:
            result, alignment = core.align_to_centres(result, known_centres)
            log.info("aligned to %d known camera centres: scale %.6g, centre RMS %.3g m",
                     alignment["centres_used"], alignment["scale"], alignment["centre_rms_m"])
        registered = [str(n) for n in result.image_names]
        summary: dict[str, Any] = {
            "selected": selected_names,
            "registered": registered,
            "not_registered": [n for n in selected_names if n not in registered],
            "registered_count": len(registered),
            "selected_count": len(selected_names),
            "models": len(models),
            "points": int(len(result.points)),
            "mean_track_length": float(np.mean(result.track_length)) if len(result.points)
            else 0.0,
            **core.reprojection_summary(result),
            "focal_px": [float(c.focal_px) for c in result.cameras],
            "camera_model": model.camera(model.image(model.reg_image_ids()[0]).camera_id)
            .model_name,
            "target": target,
            "aligned": result.aligned,
            "intrinsics": ("estimated" if not intrinsics else
                           "known, imposed after free mapping" if imposed else "known"),
            "alignment": alignment,
        }
        log.info("registered %d/%d images (%s), %d points, reprojection error mean "
                 "%.3f px, 95th percentile %.3f px", len(registered), len(images),
                 ", ".join(registered), summary["points"],
                 summary["mean_reprojection_error_px"], summary["p95_reprojection_error_px"])
        if summary["not_registered"]:
            log.warning("not registered: %s", ", ".join(summary["not_registered"]))
        model_folder = None
        if colmap_dir is not None:
            model_folder = scratch_path / "model_out"
            model_folder.mkdir()
            model.write(model_folder)
        with dio.output_transaction():
            dio.write_npz(out, "bundle", result.to_arrays())
            outputs = [Path(out)]
            if model_folder is not None:
                for item in sorted(model_folder.iterdir()):
                    final = Path(colmap_dir) / item.name
                    with dio.atomic_path(final) as temporary:
                        shutil.copyfile(item, temporary)
                    outputs.append(final)
            summary["time_s"] = round(time.perf_counter() - started, 2)
            prov.write_sidecar(out, summary, outputs=outputs)
    return summary
