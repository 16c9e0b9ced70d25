"""Parameters of ``demtool match`` (defaults: those of :func:`demtool.match.match`).

The command's options are generated from these fields; each default is read from the
core function's signature, so it is written once.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_defaults
from demtool.parameters import (
    TILE_FIELDS,
    Parameters,
    dry_run_field,
    parameter,
    scheduler_field,
    tile_overlap_field,
    tile_size_field,
    workers_field,
)

CORE = core_defaults("demtool.match.dense:match")  # from the source: --help loads no numba


@dataclass(frozen=True)
class MatchParams(Parameters):
    """Every option of ``demtool match`` except its files (see :func:`demtool.match.match`)."""

    template: int = parameter(CORE["template"], "Template size, px (odd).", minimum=9,
                              maximum=25, odd=True)
    threshold: float = parameter(
        CORE["threshold"], "Acceptance threshold on the LSM correlation coefficient "
        "(0.8 relaxed).", minimum=0.0, maximum=1.0, min_open=True, max_open=True)
    grid_spacing: int = parameter(
        CORE["grid_spacing"], "Pixels between template centres; pixels between four "
        "accepted nodes within 1 px of each other are interpolated bilinearly, pixels "
        "next to an accepted node but not interpolated are matched themselves.",
        minimum=1)
    levels: int = parameter(CORE["levels"], "Image pyramid levels (NCC coarse to fine).",
                            minimum=1, maximum=8)
    search_margin: float = parameter(
        CORE["search_margin"], "Pixels added to each side of a triangle's "
        "vertex-disparity range.", minimum=0.0)
    rounds: int = parameter(
        CORE["rounds"], "Densification rounds: accepted matches join the triangulation "
        "and the rejected nodes are matched again.", minimum=0)
    max_vertical: float = parameter(CORE["max_vertical"], "Largest row offset of an "
                                    "accepted match, px.", minimum=0.0, min_open=True)
    weighting: float = parameter(
        CORE["weighting"], "Gaussian LSM observation weights of this sigma, px (0 = "
        "uniform, the HiRISE study's LSM). Centre weighting resolves fine relief that a "
        "uniform template averages away.", minimum=0.0)
    refine: int = parameter(
        CORE["refine"], "Inverse-compositional Gauss-Newton iterations that refine every "
        "accepted disparity (interpolated ones from the nodes' interpolated LSM shape) "
        "with its own template; 0 = off.", minimum=0)
    sift: bool = parameter(CORE["use_sift"], "Detect SIFT seed matches (besides Förstner "
                           "corners and --rectify's).")
    workers: int = workers_field()
    # Tiles (demtool.tiling; docs/stages/scale.md): tiled, --workers is the Dask worker count
    # (processes: the matching kernels hold the GIL, demtool.tiling.local_threads).
    tile_size: int = tile_size_field()
    tile_overlap: int | None = tile_overlap_field(
        "template x 2^(levels-1) + template; the disparity range of --rectify is added on "
        "the sides")
    scheduler: str | None = scheduler_field()
    dry_run: bool = dry_run_field()

    def matcher_options(self) -> dict:
        """Keywords of :func:`demtool.match.match` (besides images, seeds and range)."""
        values = self.as_dict()
        values["use_sift"] = values.pop("sift")
        del values["workers"]
        for name in TILE_FIELDS:
            del values[name]
        return values
