"""`demtool select`: the options of :class:`demtool.select.params.SelectParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import option_types, options
from demtool.select.params import SelectParams
from demtool.stages import STAGES


@click.command(name="select", help=STAGES["select"] + """

Compares every IMAGE with the target (SIFT, Lowe's ratio test, fundamental-matrix
RANSAC, footprint overlap of the ROI) and writes OUT (selection.json) with the target
first in "selected", and every rejected image with its reason.  With --cameras/--scene
(or camera tags in the images) it records incidence, emission, phase and convergence
angles; --rank orders the selected images by a score favouring many inliers, ROI
overlap, a 25° convergence and sun-azimuth diversity.""")
@click.argument("images", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--target", required=True, type=click.Path(dir_okay=False),
              help="The target image (may also be among IMAGES; never matched with itself).")
@options.out_file("Output selection.json.")
@click.option("--roi", nargs=4, type=option_types.FLOAT, default=None,
              metavar="X0 Y0 X1 Y1", help="Region of interest in target pixels "
              "(columns X0..X1-1, rows Y0..Y1-1); default: the whole target.")
@options.path_option("--cameras", "cameras.npz (from synth) for viewing geometry.")
@options.path_option("--scene", "scene.json (from synth) for the sun direction.")
@click.option("--cache-dir", type=click.Path(file_okay=False), default=None,
              help="Feature cache folder [default: .demtool-features/ beside OUT].")
@options.parameter_options(SelectParams)
@click.pass_context
def command(ctx: click.Context, images: tuple[str, ...], target: str, out: str,
            roi: tuple[float, float, float, float] | None, cameras: str | None,
            scene: str | None, cache_dir: str | None, **values: Any) -> None:
    """Options → SelectParams → :func:`demtool.select.run.run_select`."""
    from demtool.select.run import run_select

    run_select(list(images), target, out, SelectParams.from_options(values), roi=roi,
               cameras=cameras, scene=scene, cache_dir=cache_dir,
               resolved=options.resolved_params(ctx))
