"""`demtool bundle`: the options of :class:`demtool.bundle.params.BundleParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.bundle.params import BundleParams
from demtool.commands import options
from demtool.stages import STAGES

HELP = STAGES["bundle"] + """
Takes any block of images: INPUTS is one selection.json (from `demtool select`; the target first) or
two or more image files, or --images LIST (one path a line, relative to the list file). Runs COLMAP
through pycolmap: SIFT features, exhaustive or sequential (strips: neighbours in input order)
matching with geometric verification, incremental mapping with bundle adjustment. By default all
images share one camera: COLMAP estimates its focal length and a radial term while mapping, then a
self-calibration frees the principal point and a second radial term and keeps each only where the
block determines it (docs/stages/bundle.md); a focal length the block does not determine (a
near-flat strip trades it for the flying height) is kept at the prior, 1.2 x the image size, with a
warning. --focal-px, --focal-mm with --pixel-mm (a metric camera: the pitch of the images as given,
downsampling included) or --cameras give known intrinsics (fixed unless --refine-intrinsics; one
mapping pass), and with them the relief's scale. The largest model is written to OUT (bundle.npz:
points, intensities, track lengths, reprojection errors, cameras, target index) with the sidecar
OUT.json (registered images, per-image observations and residuals, refined intrinsics and their
standard deviations). --align-cameras maps the model onto known camera centres (similarity, Umeyama
1991) so that it is metric, in the world frame.

With sensor models (--sensors MODEL, repeated, one per image in the same order: ALE ISD JSON, ISIS
cube with SPICE, ASP .tsai; ISIS cubes given as the images are their own models) the block is
adjusted in the body-fixed frame, in metres: SIFT tie points between the pairs of --matcher
(spatial: overlapping footprints of the models) are triangulated with the prior poses, then each
image's position and pointing (a constant offset, for line scanners too) and the tie points are
adjusted with priors weighted by --position-sigma (m) and --pointing-sigma (mrad). No two-view
initialisation is needed. --adjusted-dir receives the adjusted models in their own format (ISD JSON
for ISDs and cubes, .tsai for .tsai) for rectify, dem and mapproject; OUT.json reports each image's
residual, observations, change of position (m) and pointing (mrad) and their standard deviations.
Tie points fix the block's shape, not its datum (a shift, turn or scale of the whole block), which
the priors alone only place as well as their mean: --reference-dem DEM (LOLA, MOLA: a DEM on the
models' body) ties every tie point's height to the DEM's (bilinear, Huber loss; sigma:
--reference-dem-sigma metres plus the DEM's interpolation error at the point, post^2/8 x its
curvature and a measured share of post x slope), as ASP's bundle_adjust --heights-from-dem does, so
the block follows the ground; the prior block is first registered to the DEM by a search of shifts
within 3 sigmas of the priors (as ASP's pc_align before bundle_adjust), and the adjustment from
there is kept where it costs less than the one from the priors.

With --control-network NET (an ISIS control network, binary or PVL) and --sensors (no images needed)
the models are adjusted on the network's measures instead, as ISIS jigsaw and knoten do: per image
the pointing terms of --solve (angles, rates, accelerations: polynomial in time) and with
--solve-position a position bias, a priori --pointing-sigma (mrad), --angular-rate-sigma,
--angular-acceleration-sigma, --position-sigma; free points triangulated, constrained points
weighted by their a priori covariance, fixed points held; measures weighted by --measure-sigma,
outliers rejected (--rejection-multiplier). The network's serial numbers are matched to the models
by their spacecraft clock (or --serials LIST: one serial a line, one per model). OUT.bundleout.txt
and OUT.points.csv report sigma0, per-image residuals and corrections, per-point residuals and the
rejected measures (jigsaw's bundleout); --adjusted-network receives the adjusted network,
--adjusted-dir the adjusted models. --reference-points SHOTS ties the points' heights to laser
altimetry (a surface through the shots, within 3 shot spacings of them; sigma per shot from the
table or --reference-points-sigma).
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
@click.option("--sensors", "sensors", multiple=True, type=click.Path(dir_okay=False),
              help="Sensor model of each image (ISD JSON, ISIS cube, .tsai), repeated, one "
              "per image in the same order: pose priors.")
@click.option("--adjusted-dir", type=click.Path(file_okay=False),
              help="Write the adjusted sensor models into this folder (with --sensors or "
              "cubes).")
@options.path_option("--reference-dem", "A DEM on the body's map (e.g. LOLA, MOLA) tying "
                     "the tie points' heights, weighted by --reference-dem-sigma: the "
                     "block's height, tilt, scale and (over relief) position (with "
                     "sensor models).")
@options.path_option("--control-network", "An ISIS control network (.net, binary or PVL) "
                     "to adjust the --sensors models on.")
@options.path_option("--adjusted-network", "With --control-network: the adjusted network (.net).")
@options.path_option("--reference-points", "With --control-network: laser altimetry shots "
                     "(LOLA RDR, MOLA PEDR, named columns) as ground control of the "
                     "points' heights (sigma: the table's or --reference-points-sigma).")
@options.path_option("--serials", "With --control-network: the serial number of each "
                     "--sensors model, one a line, same order.")
@options.parameter_options(BundleParams)
@click.pass_context
def command(ctx: click.Context, inputs: tuple[str, ...], images: str | None, out: str,
            colmap_dir: str | None, cameras: str | None, align_cameras: str | None,
            sensors: tuple[str, ...], adjusted_dir: str | None, reference_dem: str | None,
            control_network: str | None, adjusted_network: str | None, serials: str | None,
            reference_points: str | None, **values: Any) -> None:
    """Options → BundleParams → :func:`demtool.bundle.run.run_bundle`."""
    from demtool.bundle.run import run_bundle
    from demtool.cli import AppState

    options.exclusive({"--focal-px": values["focal_px"] is not None,
                       "--focal-mm": values["focal_mm"] is not None,
                       "--cameras": cameras is not None})
    options.exclusive({"INPUTS": bool(inputs), "--images": images is not None},
                      exactly_one=control_network is None)
    if len(inputs) > 1 and any(name.lower().endswith(".json") for name in inputs):
        raise click.BadParameter("a selection.json comes alone, not with image files",
                                 param_hint="INPUTS")
    state = ctx.find_object(AppState)
    run_bundle(list(inputs), out, BundleParams.from_options(values), image_list=images,
               colmap_dir=colmap_dir, cameras_path=cameras, align_path=align_cameras,
               sensors=list(sensors) or None, adjusted_dir=adjusted_dir,
               reference_dem=reference_dem, control_network=control_network,
               adjusted_network=adjusted_network, serials=serials,
               reference_points=reference_points,
               verbose=state is not None and state.verbosity > 0,
               resolved=options.resolved_params(ctx))
