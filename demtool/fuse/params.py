"""Parameters of ``demtool fuse`` (core: :mod:`demtool.fuse.core`).

The command's options are generated from these fields; the methods and alignments come
from the cores (read from their source, so ``demtool fuse --help`` does not load numba).
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_constant
from demtool.parameters import Parameters, parameter
from demtool.tiling import dry_run_field, scheduler_field, tile_overlap_field, tile_size_field

METHODS = core_constant("demtool.fuse.core:METHODS")
ALIGN_METHODS = core_constant("demtool.compare.align:ALIGN_METHODS")


@dataclass(frozen=True)
class FuseParams(Parameters):
    """Every option of ``demtool fuse`` except its files.

    Attributes
    ----------
    method : str
        ``huber`` (Huber's M-estimate, no rejection; the default: below the mean's RMSE
        on every synthetic block of ``bench/fuse_block.py``), ``mean`` (weighted mean
        after outlier rejection; error rasters optional) or ``median`` (weighted median
        by the error rasters: needs one per DEM).
    align : str
        Co-registration of each DEM to the reference (compare's ``--align``).
    outlier_k, blend, gap, weights_exponent, min_error, max_nmad, coreg_size
        See each field's help.
    workers, tile_size, tile_overlap, scheduler, dry_run
        Large mosaics in tiles on Dask (:mod:`demtool.fuse.tiled`).
    """

    method: str = parameter("huber", "Per-cell combination: weighted mean of the values kept "
                            "by the outlier rejection, weighted median by the DEMs' error "
                            "rasters (needs --error for every DEM), or huber: Huber's "
                            "M-estimate of every value, its scale the larger of the cell's "
                            "and the whole stack's NMAD (no rejection: a blunder's influence "
                            "is bounded).", choices=METHODS, what="method")
    align: str = parameter("nuth-kaab", "Co-registration of each DEM to the reference "
                           "(as compare --align); its shift is logged and applied.",
                           choices=ALIGN_METHODS, what="alignment method")
    outlier_k: float = parameter(3.0, "Per cell, drop heights farther from the cell's median "
                                 "than this many NMADs (mean and median).", minimum=1.0)
    blend: float = parameter(32.0, "Blending length, cells: a DEM's weight falls off over "
                             "this distance to its border (0 = no blending).", minimum=0.0)
    gap: float = parameter(16.0, "Gaps in a DEM up to about twice this wide, cells, are not "
                           "borders: its weights fall off towards its footprint's edge, not "
                           "around each hole (0 = around every hole).", minimum=0.0)
    weights_exponent: float = parameter(2.0, "Exponent of the border weights (ASP dem_mosaic "
                                        "--weights-exponent).", minimum=0.0, min_open=True)
    min_error: float = parameter(0.01, "Floor of the error rasters, metres.", minimum=0.0,
                                 min_open=True)
    max_nmad: float | None = parameter(None, "Leave out a DEM whose NMAD against the median "
                                       "of the others (after alignment) exceeds this, "
                                       "metres (default: keep every DEM).", minimum=0.0,
                                       min_open=True)
    t_srs: str | None = parameter(None, "CRS of the fused grid, any PROJ knows (EPSG:32740, an "
                                  "IAU_2015 projected code, a PROJ string), at the first "
                                  "DEM's spacing (default: the first DEM's grid).",
                                  metavar="CRS")
    coreg_size: int = parameter(1024, "Co-registration window: at most this many cells a "
                                "side, centred on each DEM's overlap with the reference.",
                                minimum=64)
    workers: int = parameter(0, "Tiled: tiles computed at a time, on threads of this "
                             "process (0 or 1: one after the other).", minimum=0)
    tile_size: int = tile_size_field()
    tile_overlap: int | None = tile_overlap_field("--blend + 2 × --gap + 2")
    scheduler: str | None = scheduler_field()
    dry_run: bool = dry_run_field()
