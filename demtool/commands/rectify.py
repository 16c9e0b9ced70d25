"""`demtool rectify`: the options of :class:`demtool.rectify_params.RectifyParams` and one
call."""

from __future__ import annotations

from typing import Any

import click

from demtool import option_types, options
from demtool.rectify_params import RectifyParams
from demtool.stages import STAGES


@click.command(name="rectify", help=STAGES["rectify"] + """

Writes OUT/left_rect.tif and OUT/right_rect.tif (NaN outside the warped images),
OUT/rectify.npz (H_left, H_right, F, inlier control points, disparity range) and
OUT/rectify.npz.json.  Rectified rows correspond; disparity d = x_left - x_right,
centred on zero over the control points.""")
@options.input_file("left")
@options.input_file("right")
@options.out_dir("Output folder for left_rect.tif, right_rect.tif and rectify.npz.")
@options.parameter_options(RectifyParams)
@click.option("--disparity-range", type=(option_types.FLOAT, option_types.FLOAT), default=None,
              metavar="MIN MAX", help="Disparity search range to record, px (default: from "
                                      "the control points).")
@click.pass_context
def command(ctx: click.Context, left: str, right: str, out: str, **values: Any) -> None:
    """Options → RectifyParams → :func:`demtool.runs.rectify.run_rectify`."""
    from demtool.runs.rectify import run_rectify

    run_rectify(left, right, out, RectifyParams.from_options(values),
                resolved=options.resolved_params(ctx))
