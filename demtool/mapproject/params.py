"""Parameters of ``demtool mapproject`` (beside the single-module core
:mod:`demtool.mapproject.core`; defaults of the lattice read from
:func:`demtool.mapproject.core.image_coordinates`)."""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_defaults
from demtool.maps import PROJECTIONS
from demtool.parameters import Parameters, parameter, seed_field
from demtool.tiling import dry_run_field, scheduler_field

# read from the source, so --help loads no numba (demtool.mapproject.core compiles kernels)
CORE = core_defaults("demtool.mapproject.core:image_coordinates")


@dataclass(frozen=True)
class MapprojectParams(Parameters):
    """Every option of ``demtool mapproject`` except its files."""

    height: float | None = parameter(None, "Project onto the reference sphere raised by this "
                                     "height, metres (instead of --dem).")
    gsd: float | None = parameter(None, "Pixel size of the orthoimage, metres (default: the "
                                  "DEM's grid, or the image's own GSD at its centre).",
                                  minimum=0.0, min_open=True)
    projection: str = parameter("auto", "Map projection of a new grid (auto: polar "
                                "stereographic poleward of 70 degrees, else "
                                "equirectangular).", choices=PROJECTIONS, what="projection")
    t_srs: str | None = parameter(None, "CRS of a new grid, any PROJ knows (EPSG:32740, an "
                                  "IAU_2015 projected code, a PROJ string), as ASP's "
                                  "--t_srs (default: --projection on the body).",
                                  metavar="CRS")
    bounds: tuple[float, float, float, float] | None = parameter(
        None, "Area to cover, degrees: LON_MIN LAT_MIN LON_MAX LAT_MAX, in −180…180 or "
        "0…360 (LON_MAX < LON_MIN: across the antimeridian; default: the image's "
        "footprint).", metavar="LON_MIN LAT_MIN LON_MAX LAT_MAX", cli=False)
    tile_size: int = parameter(1024, "Map cells per tile side (memory: about 60 bytes a "
                               "cell), in this process or on the tile engine.", minimum=16)
    step: int = parameter(CORE["step"], "First lattice spacing of the exact projection, "
                          "cells (refined until --tolerance holds).", minimum=1)
    tolerance: float = parameter(CORE["tolerance"], "Largest interpolation error of the "
                                 "image coordinates, pixels.", minimum=0.0, min_open=True)
    seed: int = seed_field()
    # The tile engine (demtool.mapproject.tiled; docs/stages/scale.md): off by default.
    workers: int = parameter(0, "Run the map tiles on the tile engine (resumable, cached "
                             "in a work folder): 1 = one after the other in this process, "
                             "N >= 2 = N tiles at a time on threads of this process; 0 = the "
                             "in-process loop.",
                             minimum=0)
    scheduler: str | None = scheduler_field()
    dry_run: bool = dry_run_field()

    def check(self) -> None:
        super().check()
        problem = bounds_problem(self.bounds)
        if problem is not None:
            self.fail("bounds", problem)


def bounds_problem(bounds) -> str | None:
    """What is wrong with ``--bounds LON_MIN LAT_MIN LON_MAX LAT_MAX`` (None: nothing).

    Shared by :meth:`MapprojectParams.check` (exit 1) and the option's callback (a usage
    error, exit 2).
    """
    if bounds is None:
        return None
    if len(bounds) != 4:
        return f"must be 4 numbers, got {len(bounds)}"
    from demtool.maps.frames import longitude_span

    lon0, lat0, lon1, lat1 = bounds
    # LON_MAX < LON_MIN: a box across the antimeridian (179.9 … −179.9) or across 0°E in
    # 0…360 (359.9 … 0.1) — read so only when that box is at most 180° wide; a wider one
    # is more likely LON_MIN and LON_MAX swapped
    wraps = lon1 < lon0
    lon0, lon1 = longitude_span(lon0, lon1)
    if not (lon0 < lon1 <= lon0 + (180.0 if wraps else 360.0) and lat0 < lat1
            and -90 <= lat0 and lat1 <= 90):
        return ("must be LON_MIN LAT_MIN LON_MAX LAT_MAX with MIN < MAX and latitudes within "
                "+-90 (LON_MAX < LON_MIN only for a box across the antimeridian, at most "
                f"180° wide), got {' '.join(f'{v:g}' for v in bounds)}")
    return None
