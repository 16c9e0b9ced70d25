"""`demtool rectify`: the options of :class:`demtool.rectify.params.RectifyParams` and one
call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import option_types, options
from demtool.rectify.params import RectifyParams
from demtool.stages import STAGES


@click.command(name="rectify", help=STAGES["rectify"] + """

Writes OUT/left_rect.tif and OUT/right_rect.tif (NaN outside the warped images),
OUT/rectify.npz (H_left, H_right, F, inlier control points, disparity range) and
OUT/rectify.npz.json.  Rectified rows correspond; disparity d = x_left - x_right,
centred on zero over the control points.

With --sensor-left and --sensor-right (frame camera models: ISD JSON, ISIS3 cube with
SPICE, .tsai, cameras.npz) the pair is rectified from the models instead (undistortion
included); a systematic vertical residual of the SIFT matches is removed by a small
pointing correction of the right camera; rectify.npz then carries both models for
`dem`.""")
@options.input_file("left")
@options.input_file("right")
@options.out_dir("Output folder for left_rect.tif, right_rect.tif and rectify.npz.")
@options.path_option("--sensor-left", "Sensor model of LEFT (frame camera): calibrated "
                     "rectification.")
@options.path_option("--sensor-right", "Sensor model of RIGHT (with --sensor-left).")
@options.parameter_options(RectifyParams)
@click.option("--disparity-range", type=(option_types.FLOAT, option_types.FLOAT), default=None,
              metavar="MIN MAX", help="Disparity search range to record, px (default: from "
                                      "the control points).")
@click.pass_context
def command(ctx: click.Context, left: str, right: str, out: str, sensor_left: str | None,
            sensor_right: str | None, **values: Any) -> None:
    """Options → RectifyParams → :func:`demtool.rectify.run.run_rectify`."""
    from demtool.rectify.run import run_rectify

    if (sensor_left is None) != (sensor_right is None):
        raise click.BadParameter("give both --sensor-left and --sensor-right, or neither",
                                 param_hint="--sensor-left/--sensor-right")
    run_rectify(left, right, out, RectifyParams.from_options(values),
                sensor_left=sensor_left, sensor_right=sensor_right,
                resolved=options.resolved_params(ctx))
