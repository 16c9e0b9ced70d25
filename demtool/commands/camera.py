"""`demtool camera`: the options of :class:`demtool.camera.params.CameraParams` and one
call."""

from __future__ import annotations

from typing import Any

import click

from demtool.camera.params import CameraParams
from demtool.commands import options
from demtool.stages import STAGES


@click.command(name="camera", help=STAGES["camera"] + """

MODEL: ALE ISD JSON (frame or line scan), ISIS3 cube with SPICE attached, ASP .tsai
(give --body), cameras.npz or bundle.npz (every camera in it, in the scene's local
frame).  Prints a table (one column per model, then one row per pair) on stdout, or
the JSON report with --json; --out also writes the JSON report (and its provenance
sidecar).  Keys: docs/stages/camera.md.""")
@options.sensor_models()
@options.parameter_options(CameraParams)
@options.json_report_option()
@options.path_option("--out", "Also write the JSON report to this file.")
@options.path_option("--footprints", "Also write each image's footprint and each pair's "
                     "overlap as GeoJSON polygons (lon/lat on the body, cut at ±180°) for "
                     "GIS tools.")
@click.pass_context
def command(ctx: click.Context, models: tuple[str, ...], as_json: bool, out: str | None,
            footprints: str | None, **values: Any) -> None:
    """Options → CameraParams → :func:`demtool.camera.run.run_camera`."""
    from demtool.camera.run import run_camera

    run_camera(models, CameraParams.from_options(values), out=out, as_json=as_json,
               resolved=options.resolved_params(ctx), footprints=footprints)
