"""`demtool bundle`: the options of :class:`demtool.bundle.params.BundleParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool import options
from demtool.bundle.params import BundleParams
from demtool.stages import STAGES

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
@options.path_option("--images", "List file of the images (one path a line, relative to "
                     "the list file).")
@options.out_file("Output bundle.npz.")
@click.option("--colmap-dir", type=click.Path(file_okay=False),
              help="Also write the COLMAP model (binary) into this folder, for COLMAP's GUI.")
@options.path_option("--cameras", "cameras.npz with known intrinsics K of the images "
                     "(matched by name).")
@options.path_option("--align-cameras", "cameras.npz with known camera centres: align the "
                     "model to them (metric world frame).")
@options.parameter_options(BundleParams)
@click.pass_context
def command(ctx: click.Context, inputs: tuple[str, ...], images: str | None, out: str,
            colmap_dir: str | None, cameras: str | None, align_cameras: str | None,
            **values: Any) -> None:
    """Options → BundleParams → :func:`demtool.runs.bundle.run_bundle`."""
    from demtool.cli import AppState
    from demtool.runs.bundle import run_bundle

    options.exclusive({"--focal-px": values["focal_px"] is not None,
                       "--cameras": cameras is not None})
    options.exclusive({"INPUTS": bool(inputs), "--images": images is not None},
                      exactly_one=True)
    if len(inputs) > 1 and any(name.lower().endswith(".json") for name in inputs):
        raise click.BadParameter("a selection.json comes alone, not with image files",
                                 param_hint="INPUTS")
    state = ctx.find_object(AppState)
    run_bundle(list(inputs), out, BundleParams.from_options(values), image_list=images,
               colmap_dir=colmap_dir, cameras_path=cameras, align_path=align_cameras,
               verbose=state is not None and state.verbosity > 0,
               resolved=options.resolved_params(ctx))
