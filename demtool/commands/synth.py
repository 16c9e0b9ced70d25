"""`demtool synth`: the options of :class:`demtool.synth.SceneParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.stages import STAGES
from demtool.synth.params import SceneParams


@click.command(name="synth", help=STAGES["synth"] + """

Writes into DIR: view_00.tif (the nadir target), view_01.tif (its stereo partner),
view_02.tif …, truth_dem.tif (map grid), truth_dem_target.tif (target pixel grid),
albedo.tif, cameras.npz, scene.json and the provenance record scene.json.json.
Defaults give the demo scene (512 × 512 DEM at 1 m, 8 views of 512 × 512 px).
With --sensor frame or linescan the scene sits on --body's sphere and each view also
gets its ISD (view_XX.json, read by every stage that takes a sensor model), plus
truth_dem_map.tif: truth heights above the sphere on the body's map over the stereo
pair's common footprint; linescan renders two views and writes no cameras.npz.""")
@options.out_dir("Output folder for the scene (created if needed).")
@options.parameter_options(SceneParams)
@click.option("--no-craters", is_flag=True, default=False, help="Same as --craters 0.")
@click.option("--sensor-model", "sensor_models", nargs=2, default=None,
              type=click.Path(exists=True, dir_okay=False),
              help="Two real frame or line-scan models (ISD, ISIS cube…): the terrain is "
                   "placed under their common footprint and rendered through windows of "
                   "them, --image-lines × --image-size px centred on it (moved inside "
                   "the image where they would leave it: a full-width window); the DEM "
                   "spacing (half the finer GSD, coarser where the DEM would pass 4096 "
                   "cells a side), size and --gsd are chosen from the windows' GSD.")
@click.pass_context
def command(ctx: click.Context, out: str, no_craters: bool, sensor_models, **values: Any
            ) -> None:
    """Options → SceneParams → :func:`demtool.synth.run.run_synth`."""
    from demtool.synth.run import run_synth

    if no_craters:
        if options.given_on_command_line(ctx, "craters") and values["craters"]:
            raise click.BadParameter("give either --craters N or --no-craters, not both",
                                     param_hint="'--no-craters'")
        values["craters"] = 0
    run_synth(out, SceneParams.from_options(values), resolved=options.resolved_params(ctx),
              sensor_models=tuple(sensor_models) if sensor_models else None)
