"""`demtool bundle`: structure from motion and bundle adjustment of selected images."""

from __future__ import annotations

import os
from pathlib import Path

import click

from demtool import options as opt
from demtool.cli import STAGES

HELP = STAGES["bundle"] + """

Takes any block of images: INPUTS is one selection.json (from `demtool select`; the
target first) or two or more image files, or --images LIST (one path a line,
relative to the list file).  Runs COLMAP through pycolmap: SIFT features,
exhaustive or sequential (strips: neighbours in input order) matching with geometric
verification, incremental mapping with bundle adjustment.  By default all images
share one camera: COLMAP estimates its focal length and a radial term while
mapping, then a self-calibration frees the principal point and a second radial term
and keeps each only where the block determines it (README, "bundle").  --focal-px or
--cameras give known intrinsics (fixed unless --refine-intrinsics; one mapping pass).
The largest model is written to OUT (bundle.npz: points, intensities, track lengths,
reprojection errors, cameras, target index) with the sidecar OUT.json (registered
images, per-image observations and residuals, refined intrinsics and their standard
deviations).  --align-cameras maps the model onto known camera centres (similarity,
Umeyama 1991) so that it is metric, in the world frame.
"""


@click.command(name="bundle", help=HELP)
@click.argument("inputs", nargs=-1, type=click.Path(dir_okay=False))
@click.option("--images", "image_list", type=click.Path(dir_okay=False),
              help="List file of the images (one path a line, relative to the list file).")
@opt.out_file("Output bundle.npz.")
@click.option("--colmap-dir", type=click.Path(file_okay=False),
              help="Also write the COLMAP model (binary) into this folder, for COLMAP's GUI.")
@click.option("--focal-px", type=click.FloatRange(min=0.0, min_open=True),
              help="Known focal length, pixels (principal point at the image centre).")
@click.option("--cameras", type=click.Path(dir_okay=False),
              help="cameras.npz with known intrinsics K of the images (matched by name).")
@click.option("--refine-intrinsics", is_flag=True,
              help="Let bundle adjustment refine known focal lengths (default: fixed).")
@click.option("--shared-camera/--per-image-camera", default=True, show_default=True,
              help="One camera for all images (one instrument) or one per image.")
@click.option("--camera-model", type=click.Choice(["SIMPLE_PINHOLE", "PINHOLE",
                                                   "SIMPLE_RADIAL", "RADIAL"]),
              help="COLMAP camera model while mapping; default SIMPLE_RADIAL (f, k), or "
                   "PINHOLE with known intrinsics.")
@click.option("--self-calibrate/--no-self-calibrate", default=True, show_default=True,
              help="With free intrinsics, refine the principal point and radial terms "
                   "k1, k2 where the block determines them.")
@click.option("--matcher", type=click.Choice(["auto", "exhaustive", "sequential"]),
              default="auto", show_default=True,
              help="Pair selection: all pairs, or neighbours in input order (strips; "
                   "auto: exhaustive up to 100 images).")
@click.option("--max-features", type=click.IntRange(min=64), default=8192, show_default=True,
              help="SIFT features per image.")
@click.option("--align-cameras", type=click.Path(dir_okay=False),
              help="cameras.npz with known camera centres: align the model to them "
                   "(metric world frame).")
@opt.seed()
@opt.workers()
@click.pass_context
def command(ctx: click.Context, inputs: tuple[str, ...], image_list: str | None, out: str,
            colmap_dir: str | None, focal_px: float | None, cameras: str | None,
            refine_intrinsics: bool, shared_camera: bool, camera_model: str | None,
            self_calibrate: bool, matcher: str, max_features: int,
            align_cameras: str | None, seed: int, workers: int) -> None:
    if focal_px is not None and cameras is not None:
        raise click.BadParameter("give either --focal-px or --cameras, not both",
                                 param_hint="--focal-px")
    if bool(inputs) == bool(image_list):
        raise click.BadParameter("give a selection.json or image files as INPUTS, or "
                                 "--images LIST (one of them)", param_hint="INPUTS")
    if len(inputs) > 1 and any(Path(p).suffix.lower() == ".json" for p in inputs):
        raise click.BadParameter("a selection.json comes alone, not with image files",
                                 param_hint="INPUTS")
    from demtool.cli import AppState

    state = ctx.find_object(AppState)
    verbose = state is not None and state.verbosity > 0
    run_bundle(list(inputs), out, image_list=image_list, colmap_dir=colmap_dir,
               focal_px=focal_px, cameras_path=cameras, refine_intrinsics=refine_intrinsics,
               shared_camera=shared_camera, camera_model=camera_model,
               self_calibrate=self_calibrate, matcher=matcher, max_features=max_features,
               align_path=align_cameras, seed=seed, workers=workers, verbose=verbose,
               params=opt.resolved_params(ctx))


def read_block(inputs: list[str], image_list: str | os.PathLike | None):
    """The block of a selection.json, image paths, or a list file (demtool.bundle.inputs)."""
    from demtool import bundle as core
    from demtool import io as dio

    if image_list is not None:
        return core.read_image_list(image_list)
    if len(inputs) == 1 and Path(inputs[0]).suffix.lower() == ".json":
        return core.read_selection(dio.require_file(inputs[0], "selection file"))
    if len(inputs) == 1:
        dio.require_file(inputs[0], "image")
    return core.block_from_paths(inputs)


def run_bundle(inputs: list[str], out: str | os.PathLike, *,
               image_list: str | os.PathLike | None = None,
               colmap_dir: str | os.PathLike | None = None, focal_px: float | None = None,
               cameras_path: str | os.PathLike | None = None, refine_intrinsics: bool = False,
               shared_camera: bool = True, camera_model: str | None = None,
               self_calibrate: bool = True,
               matcher: str = "auto", max_features: int = 8192,
               align_path: str | os.PathLike | None = None, seed: int = 0, workers: int = 0,
               verbose: bool = False, params: dict | None = None) -> dict:
    """Run the bundle stage: read the block, adjust it, write bundle.npz and sidecar.

    Returns the sidecar summary.
    """
    import time

    from demtool import bundle as core
    from demtool import io as dio
    from demtool.camera import cameras_from_arrays
    from demtool.errors import InputError
    from demtool.logs import get_logger
    from demtool.provenance import Provenance

    log = get_logger("bundle")
    started = time.perf_counter()
    block = read_block(inputs, image_list)
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
    sources = [Path(image_list)] if image_list is not None else \
        [Path(inputs[0])] if block.target is not None else []
    prov = Provenance("bundle", params or {}, sources + list(block.paths)
                      + [p for p in (cameras_path, align_path) if p is not None])
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

    def intrinsics(shapes):
        if focal_px is None and known_cameras is None:
            return None
        return core.known_intrinsics(
            shapes, focal_px=focal_px, refine=refine_intrinsics,
            matrices=None if known_cameras is None else
            {n: known_cameras[n].K for n in block.names})

    core.set_colmap_verbosity(verbose)
    known = focal_px is not None or known_cameras is not None
    options = core.SfmOptions(
        shared_camera=shared_camera,
        camera_model=camera_model or ("PINHOLE" if known else "SIMPLE_RADIAL"),
        matcher=matcher, max_features=max_features, seed=seed, workers=workers)
    adjusted = core.adjust_block(images(), options, target=block.target, intrinsics=intrinsics,
                                 self_calibration=self_calibrate,
                                 keep_model=colmap_dir is not None)
    result, summary = adjusted.result, adjusted.summary
    summary["source"] = block.source
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
    with dio.output_transaction():
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
