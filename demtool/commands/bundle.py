"""`demtool bundle`: the options of :class:`demtool.bundle.params.BundleParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool import options
from demtool.bundle.params import BundleParams
from demtool.stages import STAGES

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
@options.input_file("selection")
@options.out_file("Output bundle.npz.")
@click.option("--colmap-dir", type=click.Path(file_okay=False),
              help="Also write the COLMAP model (binary) into this folder, for COLMAP's GUI.")
@options.path_option("--cameras", "cameras.npz with known intrinsics K of the images "
                     "(matched by name).")
@options.path_option("--align-cameras", "cameras.npz with known camera centres: align the "
                     "model to them (metric world frame).")
@options.parameter_options(BundleParams)
@click.pass_context
def command(ctx: click.Context, selection: str, out: str, colmap_dir: str | None,
            cameras: str | None, align_cameras: str | None, **values: Any) -> None:
    """Options → BundleParams → :func:`demtool.runs.bundle.run_bundle`."""
    from demtool.cli import AppState
    from demtool.runs.bundle import run_bundle

    options.exclusive({"--focal-px": values["focal_px"] is not None,
                       "--cameras": cameras is not None})
    state = ctx.find_object(AppState)
    run_bundle(selection, out, BundleParams.from_options(values), colmap_dir=colmap_dir,
               cameras_path=cameras, align_path=align_cameras,
               verbose=state is not None and state.verbosity > 0,
               resolved=options.resolved_params(ctx))
