"""`demtool compare`: the options of :class:`demtool.compare.params.CompareParams` and one
call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.compare.params import CompareParams
from demtool.stages import STAGES


def _profiles(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]):
    return tuple(options.parse_numbers(v, 4, "a profile (x0,y0,x1,y1)") for v in value)


def _slope_bins(ctx: click.Context, param: click.Parameter, value: Any):
    if isinstance(value, (list, tuple)):  # from a config preset
        value = ",".join(str(v) for v in value)
    bins = options.parse_numbers(value, None, "slope bins")
    if len(bins) < 2 or any(b <= a for a, b in zip(bins[:-1], bins[1:], strict=True)):
        raise click.BadParameter(f"{value!r}: slope bins must be at least two increasing "
                                 "values (degrees)")
    if bins[0] < 0 or bins[-1] > 90:
        raise click.BadParameter(f"{value!r}: slope bins must lie within 0..90 degrees")
    return bins


@click.command(name="compare", help=STAGES["compare"] + """

Puts DEM on REFERENCE's grid (NaN-aware bilinear; reprojected when both carry
different CRS; a grid in degrees is measured on a metric grid with the body's radius;
DEMs of different bodies are refused), co-registers it (--align), and writes into
--out: report.json
(RMSE, NMAD, mean, median, std, LE90, min/max, completeness %, count, the applied
shift {dx_px, dy_px, dz} added to the DEM — x right, y down in grid pixels, dz in
metres — with its uncertainty, the same shift in metres east/north/up (shift_m) and in
each input's own pixels (shift_input_px), per-slope-class statistics, effective resolution from
the spectral coherence, provenance), difference.tif, and the figures difference.png,
dems.png, profiles.png, histogram.png, completeness.png, coherence.png.  A reference
whose posts are at least twice the DEM's cells (LOLA, MOLA against a stereo DEM) is
also compared at its own resolution, beside those figures: the DEM averaged over each
reference cell minus the reference at its posts (report.json at_reference_resolution),
since sampling a coarse reference at fine cells charges the DEM with the relief the
reference cannot show.

A REFERENCE that is a table of laser altimetry shots (.csv, .tab, .txt: LOLA RDR, MOLA
PEDR, or columns named longitude/latitude/radius or height) is compared point by point:
DEM - shot at each shot (counts of shots on the DEM, on no data, outside), the
translation moving the DEM onto the shots (east/north/up metres and DEM posts, with its
formal sigma), report.json, shots.csv and a profile figure per track.""")
@options.input_file("dem")
@options.input_file("reference")
@options.out_dir("Report folder (created if needed).")
@options.parameter_options(CompareParams)
@options.path_option("--mask", "Raster of the pixels to use (non-zero = use), e.g. stable "
                     "terrain.")
@click.option("--slope-bins", default=",".join(f"{v:g}" for v in CompareParams.slope_bins),
              show_default=True, callback=_slope_bins, help="Slope class edges, degrees.")
@click.option("--profile", "profiles", multiple=True, callback=_profiles,
              metavar="X0,Y0,X1,Y1",
              help="Profile line in comparison-grid pixels (x right, y down); repeatable. "
                   "Default: through the centre, horizontal and vertical.")
@click.option("--also", multiple=True, type=click.Path(dir_okay=False),
              help="Another DEM to compare and overlay on the figures; repeatable.")
@click.option("--json", "as_json", is_flag=True, help="Print the report to stdout.")
@click.pass_context
def command(ctx: click.Context, dem: str, reference: str, out: str, mask: str | None,
            also: tuple[str, ...], as_json: bool, **values: Any) -> None:
    """Options → CompareParams → :func:`demtool.compare.run.run_compare`."""
    from demtool.compare.run import run_compare

    report = run_compare(dem, reference, out, CompareParams.from_options(values),
                         mask_path=mask, also=also, resolved=options.resolved_params(ctx))
    if as_json:
        from demtool import io as dio

        click.echo(dio.dumps_json(report))
