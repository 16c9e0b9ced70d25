"""Parameters of ``demtool compare`` (defaults: :func:`demtool.compare.compare_dems`).

The command's options are generated from these fields; the alignment methods come from
:data:`demtool.compare.align.ALIGN_METHODS` and each default from the core's signature.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_constant, core_defaults
from demtool.parameters import Parameters, parameter, seed_field

# Read from the core's source: `demtool compare --help` does not load numba.
ALIGN_METHODS = core_constant("demtool.compare.align:ALIGN_METHODS")
COMPARE = core_defaults("demtool.compare.core:compare_dems")

#: the grid a comparison is made on
GRIDS = ("reference", "dem")


@dataclass(frozen=True)
class CompareParams(Parameters):
    """Every option of ``demtool compare`` except its files.

    ``slope_bins`` (degrees) and ``profiles`` (x0, y0, x1, y1 in comparison-grid pixels)
    are lists, given by their own options.
    """

    grid: str = parameter("reference", "Which raster's grid the comparison is made on.",
                          choices=GRIDS, what="grid")
    align: str = parameter(COMPARE["align"], "Co-registration: median "
                           "vertical offset, Nuth & Kääb shift, point-to-plane ICP, or the "
                           "shift followed by ICP.", choices=ALIGN_METHODS,
                           what="alignment method")
    icp_scale: bool = parameter(COMPARE["icp_scale"], "Let ICP fit an "
                                "isotropic scale too.")
    slope_bins: tuple[float, ...] = parameter(COMPARE["slope_bins"],
                                              "Slope class edges, degrees.", cli=False)
    profiles: tuple[tuple[float, float, float, float], ...] = parameter(
        (), "Profile lines in comparison-grid pixels; default: through the centre.",
        cli=False)
    label: str | None = parameter(None, "Name of DEM in the report (default: file stem).")
    plots: bool = parameter(True, "Write the PNG figures.")
    html: bool = parameter(False, "Also write report.html: one self-contained page with "
                           "the statistics, the shift, the figures inline and the "
                           "provenance.")
    seed: int = seed_field()
    # Windowed statistics for DEMs larger than memory (demtool/compare/run_windowed.py).
    tile_size: int = parameter(0, "Compare in windows of this many cells a side, reading "
                               "both rasters window by window (0 = in memory unless the "
                               "grid needs more than --max-memory-mb).", minimum=0)
    max_memory_mb: float = parameter(4096.0, "Memory budget of a comparison, MiB; a grid "
                                     "whose in-memory comparison needs more is compared in "
                                     "windows, which keep the grid between passes while it "
                                     "fits.", minimum=1.0)
