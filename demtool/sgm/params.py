"""Parameters of ``demtool sgm`` (defaults: those of :func:`demtool.sgm.sgm`).

The command's options are generated from these fields; each default is read from the
core function's signature, so it is written once.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_constant, core_defaults
from demtool.parameters import (
    TILE_FIELDS,
    Parameters,
    dry_run_field,
    parameter,
    scheduler_field,
    seed_field,
    tile_overlap_field,
    tile_size_field,
    workers_field,
)

# Read from the core's source: `demtool sgm --help` does not load numba.
SUBPIXEL_MODES = core_constant("demtool.sgm.disparity:SUBPIXEL_MODES")
CENSUS_WINDOWS = core_constant("demtool.sgm.matcher:CENSUS_WINDOWS")
COSTS = core_constant("demtool.sgm.matcher:COSTS")
CORE = core_defaults("demtool.sgm.matcher:sgm")


@dataclass(frozen=True)
class SgmParams(Parameters):
    """Every option of ``demtool sgm`` except its files (see :func:`demtool.sgm.sgm`).

    ``min_disparity``/``num_disparities`` override the range of ``--rectify``; the
    penalties and the cost window default per cost (None).
    """

    min_disparity: int | None = parameter(
        None, "Smallest disparity searched, px (overrides --rectify).")
    num_disparities: int | None = parameter(
        None, "Number of disparities searched (overrides --rectify).", minimum=1)
    cost: str = parameter(CORE["cost"], "auto: hmi, then census compared pixel by pixel "
                          "on low-noise images, else census over a window or the "
                          "horizontal-gradient difference where HMI fails on weak texture, "
                          "a cross-checked pixel census near depth edges where HMI and "
                          "census agree (sgm.auto); hmi: hierarchical mutual information; mi: MI "
                          "iterated at full resolution from zero disparity; census; ad: "
                          "absolute difference.", choices=COSTS, what="cost")
    census_window: str = parameter(CORE["census_window"], "Census window (width x "
                                   "height).", choices=tuple(CENSUS_WINDOWS),
                                   what="census window")
    cost_window: int | None = parameter(
        CORE["cost_window"], "Odd side of the window the pixel cost is summed over "
        "[default per cost: 3 for MI, 5 for census and ad].", minimum=1, odd=True)
    paths: int = parameter(CORE["paths"], "Aggregation paths.", choices=(8, 16),
                           what="number of paths")
    p1: int | None = parameter(CORE["p1"], "Penalty of a 1-px disparity step, cost units "
                               "[default per cost].", minimum=1)
    p2: int | None = parameter(CORE["p2"], "Penalty of a larger disparity step, cost "
                               "units [default per cost].", minimum=1)
    adaptive_p2: bool = parameter(CORE["adaptive_p2"], "Lower P2 across intensity edges "
                                  "(Hirschmüller 2008).")
    mi_iterations: int = parameter(CORE["mi_iterations"], "MI iterations (mi: at full "
                                   "resolution; hmi: at the coarsest level).", minimum=1)
    subpixel: str = parameter(CORE["subpixel"], "Sub-pixel fit of the cost.",
                              choices=tuple(SUBPIXEL_MODES)[::-1], what="sub-pixel fit")
    lr_check: bool = parameter(CORE["lr_check"], "Left-right consistency check (right "
                               "disparity from the same cost).")
    lr_threshold: float = parameter(CORE["lr_threshold"], "Largest left-right difference "
                                    "kept, px.", minimum=0.0)
    speckle_size: int = parameter(CORE["speckle_size"], "Remove disparity regions "
                                  "smaller than this, px (0 = off).", minimum=0)
    speckle_range: float = parameter(CORE["speckle_range"], "Largest disparity step "
                                     "within a region, px.", minimum=0.0)
    median: int = parameter(CORE["median"], "Side of the median filter of the disparity "
                            "(1 = off).", minimum=1, odd=True)
    uniqueness: float = parameter(CORE["uniqueness"], "Drop pixels whose confidence "
                                  "(S2-S1)/S2 is below this (0.1 = OpenCV's uniquenessRatio "
                                  "10).", minimum=0.0, maximum=1.0, max_open=True)
    fill: bool = parameter(CORE["fill"], "Fill pixels left invalid from their neighbours "
                           "(occlusions from the background); they get confidence 0.")
    widen_range: int = parameter(
        2, "Match again over a wider range, at most this many times, while pixels sit "
        "exactly at a bound of a range estimated from matches (terrain beyond the "
        "matches' range; 0 = off; a range given with --min-disparity/--num-disparities "
        "is never widened).", minimum=0)
    prior_search: int = parameter(
        4, "With --prior-dem: the residual disparity searched on each side of the prior's "
        "prediction, px (widened like any estimated range while pixels sit at its bound).",
        minimum=1)
    max_memory_mb: float = parameter(
        CORE["max_memory_mb"], "Budget of the aggregated-cost volumes (and row buffers) "
        "of the strips matched at once, MiB; the image is cut into strips beyond it.",
        minimum=64)
    workers: int = workers_field()
    seed: int = seed_field()
    # Tiles (demtool.tiling; docs/stages/scale.md): tiled, --workers is the tiles at a time.
    tile_size: int = tile_size_field()
    tile_overlap: int | None = tile_overlap_field(
        "census and ad: SGM's path reach, 4 x P2 / the cost's contrast measured on the "
        "pair, + the cost's support and the filters' reach; MI costs: 64 + the cost, "
        "census and median windows + the speckle reach; the disparity range is added on "
        "the sides")
    scheduler: str | None = scheduler_field()
    dry_run: bool = dry_run_field()

    @property
    def range_given(self) -> bool:
        """Both ends of the search range given (the user's range: never widened)."""
        return self.min_disparity is not None and self.num_disparities is not None

    @property
    def widenings(self) -> int:
        """Re-matches allowed by :func:`demtool.sgm.widen.sgm_widening`: ``widen_range``
        for a range estimated from matches, 0 for one given with the options."""
        return 0 if self.range_given else self.widen_range

    def matcher_options(self) -> dict:
        """Keywords of :func:`demtool.sgm.sgm` besides the images and the range."""
        values = self.as_dict()
        del values["min_disparity"], values["num_disparities"], values["widen_range"]
        del values["prior_search"]
        for name in TILE_FIELDS:
            del values[name]
        return values
