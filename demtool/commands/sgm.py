"""`demtool sgm`: the options of :class:`demtool.sgm.params.SgmParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.sgm.params import SgmParams
from demtool.stages import STAGES


@click.command(name="sgm", help=STAGES["sgm"] + """

Reads the rectified pair LEFT_RECT and RIGHT_RECT (as written by demtool rectify; NaN
outside the warped images never matches) and writes OUT, the float32 disparity in the
left rectified image's frame (x_right = x_left - d, NaN = invalid), and OUT.json.  The
default cost "auto" starts with hierarchical mutual information (HMI, 1/16 → 1); on images
of little noise it uses census compared pixel by pixel, averaged with HMI where the two
agree; on noisy or weakly textured ones census summed over a window or the difference of
horizontal gradients where HMI fails; the log and OUT.json say which cost, which pixels
passed the left-right check and which were filled.

Two orthoimages of demtool mapproject on one grid (map-projected stereo, line
scanners), or two ISIS cam2map cubes of LRO NAC, CTX or HiRISE on one grid, are matched
along map x instead, the range from their SIFT matches; OUT is then on the left ortho's
grid and CRS, for dem --mapprojected.""")
@options.input_file("left_rect")
@options.input_file("right_rect")
@options.out_file("Output disparity GeoTIFF.")
@options.path_option("--rectify", "rectify.npz whose disparity_range sets the search range.")
@options.path_option("--prior-dem", "DEM on the body's map (e.g. demtool fuse of the block's "
                     "pairs) to match around: the right image is warped by the disparity it "
                     "predicts and only the residual is searched (--prior-search); needs a "
                     "calibrated --rectify.")
@options.parameter_options(SgmParams)
@options.path_option("--confidence", "Also write a confidence raster (0..1) here.")
@options.path_option("--classes", "Also write the class of each pixel here (uint8: 0 "
                     "invalid, 1 matched, 2 filled occlusion, 3 filled mismatch, 4 matched "
                     "at a range bound; untiled runs).")
@click.pass_context
def command(ctx: click.Context, left_rect: str, right_rect: str, out: str, rectify: str | None,
            confidence: str | None, classes: str | None, prior_dem: str | None,
            **values: Any) -> None:
    """Options → SgmParams → :func:`demtool.sgm.run.run_sgm`."""
    from demtool.sgm.run import run_sgm

    result = run_sgm(left_rect, right_rect, out, SgmParams.from_options(values),
                     rectify=rectify, confidence=confidence, classes=classes,
                     prior_dem=prior_dem,
                     resolved=options.resolved_params(ctx))
    if getattr(result, "dry_run", None):  # --dry-run: the plan on stdout
        click.echo(result.dry_run)
