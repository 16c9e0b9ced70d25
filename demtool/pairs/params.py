"""Parameters of ``demtool pairs`` (core: :mod:`demtool.pairs.core`)."""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_defaults
from demtool.parameters import Parameters, parameter

VERDICTS = core_defaults("demtool.pairs.core:pair_verdicts")


@dataclass(frozen=True)
class PairsParams(Parameters):
    """Every option of ``demtool pairs`` except its files and ``--json``."""

    body: str | None = parameter(
        None, "Body of the models, by name or NAIF id (as camera --body).", metavar="BODY")
    min_overlap: float = parameter(VERDICTS["min_overlap"], "Smallest fraction of each "
                                   "footprint the other covers.", minimum=0.0, maximum=1.0)
    min_convergence: float = parameter(VERDICTS["min_convergence"], "Smallest convergence "
                                       "angle, degrees.", minimum=0.0, maximum=180.0)
    max_convergence: float = parameter(VERDICTS["max_convergence"], "Largest convergence "
                                       "angle, degrees.", minimum=0.0, maximum=180.0)
    min_bh: float = parameter(VERDICTS["min_bh"], "Smallest base-to-height ratio.",
                              minimum=0.0)
    max_bh: float = parameter(VERDICTS["max_bh"], "Largest base-to-height ratio.",
                              minimum=0.0)
    max_sun_difference: float = parameter(VERDICTS["max_sun_difference"], "Largest angle "
                                          "between the two images' sun directions, degrees.",
                                          minimum=0.0, maximum=180.0)
    best_bh: float = parameter(VERDICTS["best_bh"], "B/H the ranking prefers.", minimum=0.0,
                               min_open=True)
    max_pairs: int = parameter(0, "Keep at most this many pairs, best first (0 = all).",
                               minimum=0)
    points_per_edge: int = parameter(16, "Footprint samples along each image edge.",
                                     minimum=2)

    def check(self) -> None:
        super().check()
        if self.min_convergence > self.max_convergence:
            self.fail("min_convergence", f"must be <= --max-convergence "
                      f"{self.max_convergence:g}, got {self.min_convergence:g}")
        if self.min_bh > self.max_bh:
            self.fail("min_bh", f"must be <= --max-bh {self.max_bh:g}, got {self.min_bh:g}")
