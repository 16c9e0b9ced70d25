"""`demtool dem`: the options of :class:`demtool.dem.params.DemParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.dem.params import DemParams
from demtool.stages import STAGES

HELP = STAGES["dem"] + """
Two forms. From bundle points (BAM route): `demtool dem --points bundle.npz [--distance D |
--scene scene.json] --out dem.tif` projects the points into the target camera; heights come from
eq. 2 of the NavCam study (depth offset (z/mean(z) - 1)·D, negated) or, for an aligned bundle,
are metric. Densified BAM DEM: `--dense DISPARITY RECTIFY` (repeatable) adds a matched pair of
the block, triangulated with the bundle's cameras and merged cell by cell with its points
(docs/stages/dem.md; match with `sgm --no-fill` so filled occlusions count as gaps). From a
disparity map (SIAM route): `demtool dem --disparity disparity.tif --rectify rectify.npz
(--reference REF.tif | --cameras cameras.npz) --out dem.tif` maps disparities back through the
inverse rectification and either fits a robust 3-D projective transformation to the reference
DEM (on the target grid) or triangulates with the known cameras. With a calibrated rectify.npz
(`rectify --sensor-left/--sensor-right`), neither is given: every valid disparity is
triangulated through the two sensor models in the body-fixed frame and OUT is a DEM on the
body's map (heights above the reference sphere, the body's IAU CRS, --projection, --gsd,
--max-ray-gap, --error-out). Models with no body (rover, lander, lab rig, drone: .tsai without a
body, cameras.npz, OpenCV/COLMAP pinholes) are triangulated in their own frame and OUT is a DEM
on a local metric grid (frame=map:local, no CRS): heights along the frame's +Z or --up X,Y,Z
(e.g. 0,0,-1 when the frame's Z points down), the grid's x axis the frame's X projected normal
to up. --points-out (calibrated routes) also writes the points as PLY, LAS or LAZ (by its
suffix; on a body with the DEM's CRS) for tools that grid clouds. Every calibrated route drops
points behind either camera and rays that miss by more than --max-ray-gap, and says how many.
Map-projected stereo (line scanners, ASP's route): `demtool dem --disparity D --mapprojected
LEFT_ORTHO RIGHT_ORTHO --out dem.tif`, D matched by sgm between two orthoimages of demtool
mapproject on one grid: each left cell (x, y) and its right cell (x - d, y) are mapped back to
raw pixels through the surface and sensor model named in the orthoimages' tags and triangulated
as above (DEM on the orthos' map).

Every route removes outliers with a local median test, fills the gaps with D'Errico's
spring-metaphor interpolation and optionally median-filters. The points, --cameras and
--reference routes write OUT in the target image frame (frame=image:<target>), pixel spacing =
GSD (--gsd, scene.json gsd_m, the reference's spacing, or estimated as distance / focal length),
heights in metres positive toward the camera; the sensor-model and map-projected routes write it
on the body's map.
"""


@click.command(name="dem", help=HELP)
@options.path_option("--points", "bundle.npz from `demtool bundle` (BAM route).")
@options.path_option("--disparity", "Disparity GeoTIFF in the left rectified frame (SIAM route).")
@options.path_option("--rectify", "rectify.npz of the pair (with --disparity).")
@options.path_option("--reference", "Reference DEM on the target grid (e.g. the BAM DEM): "
                     "uncalibrated projective fit.")
@options.path_option("--cameras", "cameras.npz with the pair's cameras: calibrated "
                     "triangulation.")
@click.option("--mapprojected", nargs=2, type=click.Path(dir_okay=False), default=None,
              metavar="LEFT_ORTHO RIGHT_ORTHO",
              help="The two orthoimages (demtool mapproject, or ISIS cam2map cubes of a "
                   "line-scan camera: its camera from the cube's tables, the surface its "
                   "Mapping ellipsoid) the disparity was matched on.")
@click.option("--dense", nargs=2, type=click.Path(dir_okay=False), multiple=True,
              metavar="DISPARITY RECTIFY",
              help="With --points: a pair's disparity and rectify.npz (repeatable) to "
                   "densify the BAM DEM.")
@options.path_option("--scene", "scene.json with distance_m and gsd_m (metadata from synth).")
@options.parameter_options(DemParams)
@options.path_option("--interpolated-mask", "Also write a raster: 1 where interpolated, 0 "
                     "where measured.")
@options.path_option("--error-out", "Sensor-model routes: also write each cell's ray gap, m.")
@options.vector_option("--up", help_text="Local-frame models: the up direction of heights, "
                       "models' frame (default +Z; 0,0,-1 for a z-down rover frame).")
@options.path_option("--points-out", "Calibrated --disparity routes: also write the "
                     "triangulated points as a point cloud, PLY, LAS or LAZ by the suffix "
                     "(on a body: map x, y and height in the DEM's CRS; local-frame models: "
                     "the models' frame), with each point's ray gap and image brightness.")
@options.out_file("Output DEM GeoTIFF.")
@click.pass_context
def command(ctx: click.Context, points: str | None, disparity: str | None,
            rectify: str | None, reference: str | None, cameras: str | None,
            scene: str | None, mapprojected: tuple[str, str] | None,
            interpolated_mask: str | None, error_out: str | None,
            up: tuple[float, float, float] | None, points_out: str | None,
            dense: tuple[tuple[str, str], ...], out: str,
            **values: Any) -> None:
    """Check the form (points or disparity), call :func:`demtool.dem.run.run_dem`."""
    from demtool.dem.run import run_dem

    if mapprojected is not None and disparity is None:
        raise click.BadParameter("--mapprojected needs --disparity", param_hint="--mapprojected")
    if dense and points is None:
        raise click.BadParameter("--dense densifies the BAM route: it needs --points "
                                 "bundle.npz", param_hint="--dense")
    options.exclusive({"--points": points is not None, "--disparity": disparity is not None},
                      exactly_one=True)
    if mapprojected is not None:
        if rectify or reference or cameras:
            raise click.BadParameter("--mapprojected takes no --rectify, --reference or "
                                     "--cameras", param_hint="--mapprojected")
    elif disparity is not None:
        if rectify is None:
            raise click.BadParameter("--disparity needs --rectify (or --mapprojected)",
                                     param_hint="--rectify")
        options.exclusive({"--reference": reference is not None,
                           "--cameras": cameras is not None})
    elif rectify or reference or cameras or error_out or up or points_out:
        raise click.BadParameter("--rectify, --reference, --cameras, --error-out, --up and "
                                 "--points-out belong to the --disparity form",
                                 param_hint="--points")
    summary = run_dem(out, DemParams.from_options(values), points_path=points,
                      disparity_path=disparity, rectify_path=rectify,
                      reference_path=reference, cameras_path=cameras, scene_path=scene,
                      mask_path=interpolated_mask, error_path=error_out,
                      mapprojected=mapprojected, up=up, points_out=points_out,
                      dense=dense, resolved=options.resolved_params(ctx))
    if summary.get("dry_run"):  # --dry-run (tiles): the plan on stdout
        click.echo(summary["dry_run"])
