"""`demtool mapproject`: the options of :class:`demtool.mapproject.params.MapprojectParams`
and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import option_types, options
from demtool.mapproject.params import MapprojectParams
from demtool.stages import STAGES


def _bounds(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
    from demtool.mapproject.params import bounds_problem

    problem = bounds_problem(value)
    if problem is not None:
        raise click.BadParameter(problem)
    return value


@click.command(name="mapproject", help=STAGES["mapproject"] + """

Every cell of the map grid is a ground point (map x, y -> lon, lat -> body-fixed XYZ
at the DEM's height, or at --height above the body's reference sphere), projected into
IMAGE through the sensor model and resampled there (bicubic); NaN where the ground is
not seen.  The grid is the DEM's lattice over the image's footprint, or a new one from
--gsd/--projection/--bounds.  OUT is tagged with the sensor model and the surface
(mapproject_sensor, mapproject_surface, mapproject_dem / mapproject_height_m) so that
later stages (dem --mapprojected, refine) can undo the projection.""")
@options.input_file("image")
@options.path_option("--sensor", "Sensor model of IMAGE (ALE ISD JSON, ISIS3 cube with "
                     "SPICE, ASP .tsai).", required=True)
@options.path_option("--dem", "DEM on the body's map to project onto (heights above the "
                     "reference sphere).")
@options.path_option("--grid-like", "Write OUT on this raster's map grid (CRS, transform, "
                     "size), e.g. the other orthoimage of a stereo pair.")
@options.path_option("--pair-sensor", "The other image's sensor model of a stereo pair: "
                     "the new grid's x axis runs along the pair's parallax (an oblique "
                     "Mercator), so sgm finds it along map x whatever the flight direction.")
@options.out_file("Orthoimage (GeoTIFF).")
@options.path_option("--angles-out", "Also write incidence, emission and phase angles "
                     "(degrees, 3 bands) on the same grid.")
@options.parameter_options(MapprojectParams)
@click.option("--bounds", type=(option_types.FLOAT,) * 4, default=None, callback=_bounds,
              metavar="LON_MIN LAT_MIN LON_MAX LAT_MAX",
              help="Area to cover, degrees, in −180…180 or 0…360 (LON_MAX < LON_MIN: a box "
                   "across the antimeridian; default: the image's footprint).")
@click.pass_context
def command(ctx: click.Context, image: str, sensor: str, dem: str | None, grid_like: str | None,
            pair_sensor: str | None, out: str, angles_out: str | None, **values: Any) -> None:
    """Options -> MapprojectParams -> :func:`demtool.mapproject.run.run_mapproject`."""
    from demtool.mapproject.run import run_mapproject

    options.exclusive({"--dem": dem is not None, "--height": values.get("height") is not None},
                      exactly_one=True)
    run_mapproject(image, sensor, out, MapprojectParams.from_options(values), dem_path=dem,
                   angles_out=angles_out, grid_like=grid_like, pair_sensor=pair_sensor,
                   resolved=options.resolved_params(ctx))
