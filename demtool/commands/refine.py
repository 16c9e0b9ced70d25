"""`demtool refine`: the options of :class:`demtool.refine.params.RefineParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import option_types, options
from demtool.refine.params import RefineParams
from demtool.stages import STAGES


@click.command(name="refine", help=STAGES["refine"] + """

Refines DEM with the shading of IMAGE (Grumpe & Wöhler 2014): minimises
EI + δ·Egrad + γ·Eint + τ·Edepth over slopes and heights, with a local albedo
(Gaussian σ_ρ) re-estimated as the DEM changes, shadows excluded, and the low-passed
heights tied to the input so the absolute heights stay.  Sun and view come from the
image's tags (written by `demtool synth`) unless given; directions are in the grid
frame (x image right, y image up, z toward the camera).  Defaults: the NavCam and
LRO NAC studies.

On the body's map (a DEM with a CRS): IMAGE is an orthoimage of `demtool mapproject`
(or a raw image with --sensor, map-projected here); the sun and view come from the
sensor model in each point's local east-north-up frame, per tile where they vary by
more than --max-illumination-change; a DEM in degrees is put on a metric grid with the
body's radius; a map image with no sensor model (a mosaic) is refused unless the sun
is given.""")
@options.input_file("image")
@options.input_file("dem")
@options.out_file("Refined DEM (GeoTIFF, same grid as DEM); a sidecar OUT.json is written "
                  "beside it.")
@click.option("--sun-azimuth", type=option_types.FLOAT, default=None,
              help="Sun azimuth, degrees clockwise from image up toward image right.")
@click.option("--sun-elevation", type=option_types.FloatRange(min=-90.0, max=90.0), default=None,
              help="Sun elevation above the horizontal, degrees.")
@options.vector_option("--sun-vector", help_text="Direction toward the sun in the grid frame "
                       "(instead of the angles).")
@options.vector_option("--view", "view_vector", help_text="Direction toward the camera in the "
                       "grid frame [default: image tag view_vector_grid, else nadir 0,0,1].")
@options.parameter_options(RefineParams)
@options.path_option("--albedo-out", "Also write the local albedo map (GeoTIFF, DEM grid).")
@options.path_option("--sensor", "Sensor model of a raw IMAGE, map-projected onto a DEM on the "
                     "body's map (an orthoimage of `demtool mapproject` names its own).")
@click.pass_context
def command(ctx: click.Context, image: str, dem: str, out: str, sun_azimuth: float | None,
            sun_elevation: float | None, sun_vector: Any, view_vector: Any,
            albedo_out: str | None, sensor: str | None, **values: Any) -> None:
    """Check option combinations, call :func:`demtool.refine.run.run_refine`."""
    from demtool.refine.run import run_refine

    if (sun_azimuth is None) != (sun_elevation is None):
        raise click.BadParameter("give both --sun-azimuth and --sun-elevation",
                                 param_hint="'--sun-azimuth/--sun-elevation'")
    options.exclusive({"--sun-vector": sun_vector is not None,
                       "--sun-azimuth/--sun-elevation": sun_azimuth is not None})
    run_refine(image, dem, out, RefineParams.from_options(values), sun_azimuth=sun_azimuth,
               sun_elevation=sun_elevation, sun_vector=sun_vector, view_vector=view_vector,
               albedo_out=albedo_out, sensor_path=sensor, resolved=options.resolved_params(ctx))
