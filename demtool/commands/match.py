"""`demtool match`: the options of :class:`demtool.match.params.MatchParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.match.params import MatchParams
from demtool.stages import STAGES


@click.command(name="match", help=STAGES["match"] + """

Matches LEFT and RIGHT, a rectified pair (as written by demtool rectify), or the
original pair together with --rectify RECTIFY_NPZ (then warped here onto the
rectified canvas).  Writes OUT, the float32 disparity in the left rectified frame
(x_right = x_left - d, NaN = not matched), and OUT.json.  Seeds: SIFT, Förstner
corners and the control points of --rectify, verified by LSM; a match is accepted
when its final LSM correlation coefficient reaches --threshold.

Two orthoimages of demtool mapproject on one grid (no --rectify) are matched along
map x, seeded by their SIFT matches; OUT is then on the left ortho's grid and CRS.""")
@options.input_file("left")
@options.input_file("right")
@options.out_file("Output disparity GeoTIFF.")
@options.path_option("--rectify", "rectify.npz: seed matches, disparity range, and "
                     "homographies to warp an original (unrectified) pair.")
@options.parameter_options(MatchParams)
@options.path_option("--correlation-out", "Also write the LSM correlation coefficient of "
                     "every evaluated template.")
@options.path_option("--sigma-out", "Also write the LSM standard deviation of the accepted "
                     "disparities, px.")
@click.pass_context
def command(ctx: click.Context, left: str, right: str, out: str, rectify: str | None,
            correlation_out: str | None, sigma_out: str | None, **values: Any) -> None:
    """Options → MatchParams → :func:`demtool.match.run.run_match`."""
    from demtool.match.run import run_match

    result = run_match(left, right, out, MatchParams.from_options(values), rectify=rectify,
                       correlation_out=correlation_out, sigma_out=sigma_out,
                       resolved=options.resolved_params(ctx))
    if getattr(result, "dry_run", None):  # --dry-run: the plan on stdout
        click.echo(result.dry_run)
