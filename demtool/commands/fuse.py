"""`demtool fuse`: the options of :class:`demtool.fuse.params.FuseParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.fuse.params import FuseParams
from demtool.stages import STAGES


@click.command(name="fuse", help=STAGES["fuse"] + """

DEM...: DEMs of one area (pairs, routes or dates) on one body.  Each is put on the
fused grid (the union of their extents on the first DEM's CRS and spacing, or
--grid-like's), co-registered to the reference (the first DEM or --reference; compare's
--align, each shift logged) and combined cell by cell: Huber's M-estimate, a blunder's
influence bounded (--method huber, the default), the weighted mean after per-cell
outlier rejection (--method mean), or the weighted median by each DEM's error raster
(--method median), with weights falling off towards each DEM's border (--blend, as ASP
dem_mosaic).  Error rasters: --error, one per DEM in order, or <stem>_error.tif beside
a DEM.  Writes --out and, beside it, <stem>_count.tif (DEMs per cell),
<stem>_spread.tif (NMAD of the heights) and <stem>_error.tif (combined error), plus the
sidecar <out>.json with each DEM's shift.""")
@click.argument("dems", nargs=-1, required=True, type=click.Path(dir_okay=False),
                metavar="DEM...")
@options.out_file("Fused DEM (GeoTIFF).")
@click.option("--error", "errors", multiple=True, type=click.Path(dir_okay=False),
              help="Error raster of a DEM (metres, e.g. dem --error-out); repeat once per "
                   "DEM, in the DEMs' order.")
@options.path_option("--reference", "DEM to co-register every DEM to (default: the first).")
@options.path_option("--grid-like", "Raster whose grid the fused DEM is written on.")
@options.parameter_options(FuseParams)
@click.pass_context
def command(ctx: click.Context, dems: tuple[str, ...], out: str, errors: tuple[str, ...],
            reference: str | None, grid_like: str | None, **values: Any) -> None:
    """Options → FuseParams → :func:`demtool.fuse.run.run_fuse`."""
    from demtool.fuse.run import run_fuse

    run_fuse(dems, out, FuseParams.from_options(values), errors=errors or None,
             reference=reference, grid_like=grid_like, resolved=options.resolved_params(ctx))
