"""Parameters of ``demtool dem`` (defaults: the core's, :mod:`demtool.dem.routes`).

The command's options are generated from these fields; the outlier test's defaults are
read from the core's :class:`OutlierOptions`, so each is written once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from demtool.core_source import core_constant, core_defaults
from demtool.parameters import (
    Parameters,
    dry_run_field,
    parameter,
    scheduler_field,
    seed_field,
    tile_overlap_field,
    tile_size_field,
)

if TYPE_CHECKING:
    from demtool.dem.routes import OutlierOptions

# Read from the cores' source (dem.routes imports the DEM solvers, maps.projections pyproj's
# helpers), which every command run with a preset naming [dem] would import otherwise.
OUTLIERS = core_defaults("demtool.dem.routes:OutlierOptions")
PROJECTIONS = core_constant("demtool.maps.projections:PROJECTIONS")


@dataclass(frozen=True)
class DemParams(Parameters):
    """Every option of ``demtool dem`` except its files."""

    target: str | None = parameter(None, "Target view name (default: the bundle's target, or "
                                   "the left image of the pair).")
    distance: float | None = parameter(None, "Spacecraft-surface distance D, metres (eq. 2; "
                                       "unaligned bundles).", minimum=0.0, min_open=True)
    gsd: float | None = parameter(None, "Pixel spacing of the output, metres (default: from "
                                  "metadata or estimated).", minimum=0.0, min_open=True)
    median: int = parameter(0, "Median filter after filling, odd size in px (0 = off).",
                            minimum=0, odd=True)
    outlier_neighbours: int = parameter(OUTLIERS["neighbours"],
                                        "Neighbours of the local median outlier test.",
                                        minimum=3)
    outlier_threshold: float = parameter(OUTLIERS["threshold"],
                                         "Outlier threshold in local NMADs (0 = no outlier "
                                         "removal).", minimum=0.0)
    mask_band: bool = parameter(False, "Write the interpolation mask as a second band of OUT.",
                                flag="--mask-band")
    projection: str = parameter("auto", "Map projection of a DEM triangulated through sensor "
                                "models (auto: polar stereographic poleward of 70 degrees).",
                                choices=PROJECTIONS, what="projection")
    t_srs: str | None = parameter(None, "CRS of a DEM triangulated through sensor models, any "
                                  "PROJ knows (EPSG:32740, an IAU_2015 projected code, a PROJ "
                                  "string), as ASP's point2dem --t_srs (default: --projection "
                                  "on the body, or the orthoimages' CRS).", metavar="CRS")
    max_ray_gap: float | None = parameter(
        None, "Calibrated routes and --dense: drop points whose rays miss each other by "
        "more, metres (an unaligned bundle's model units with --dense; default: median gap + "
        "max(4 NMAD, 2 GSD)).", minimum=0.0, min_open=True)
    seed: int = seed_field()
    # Tiles over the output grid (demtool.dem.tiled; docs/stages/scale.md): disparity route with
    # --cameras only.
    workers: int = parameter(0, "Tiled runs: tiles computed at a time, on threads of this "
                             "process (0 or 1 = one after the other).", minimum=0)
    tile_size: int = tile_size_field()
    tile_overlap: int | None = tile_overlap_field(
        "64 px + the median filter's half width, 16 × the coarse solve's decimation when it "
        "decimates")
    scheduler: str | None = scheduler_field()
    dry_run: bool = dry_run_field()

    def outliers(self) -> OutlierOptions:
        """The outlier test of the core."""
        from demtool.dem.routes import OutlierOptions

        return OutlierOptions(neighbours=self.outlier_neighbours,
                              threshold=self.outlier_threshold)
