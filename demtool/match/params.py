"""Parameters of ``demtool match`` (defaults: those of :func:`demtool.match.match`).

The command's options are generated from these fields; each default is read from the
core function's signature, so it is written once.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.match.dense import match
from demtool.parameters import Parameters, core_default, parameter, workers_parameter


def _default(name: str):
    return core_default(match, name)


@dataclass(frozen=True)
class MatchParams(Parameters):
    """Every option of ``demtool match`` except its files (see :func:`demtool.match.match`)."""

    template: int = parameter(_default("template"), "Template size, px (odd).", minimum=9,
                              maximum=25, odd=True)
    threshold: float = parameter(
        _default("threshold"), "Acceptance threshold on the LSM correlation coefficient "
        "(0.8 relaxed).", minimum=0.0, maximum=1.0, min_open=True, max_open=True)
    grid_spacing: int = parameter(
        _default("grid_spacing"), "Pixels between template centres; pixels between four "
        "accepted nodes are interpolated bilinearly, others stay NaN.", minimum=1)
    levels: int = parameter(_default("levels"), "Image pyramid levels (NCC coarse to fine).",
                            minimum=1, maximum=8)
    search_margin: float = parameter(
        _default("search_margin"), "Pixels added to each side of a triangle's "
        "vertex-disparity range.", minimum=0.0)
    rounds: int = parameter(
        _default("rounds"), "Densification rounds: accepted matches join the triangulation "
        "and the rejected nodes are matched again.", minimum=0)
    max_vertical: float = parameter(_default("max_vertical"), "Largest row offset of an "
                                    "accepted match, px.", minimum=0.0, min_open=True)
    weighting: float = parameter(
        _default("weighting"), "Gaussian LSM observation weights of this sigma, px (0 = "
        "uniform, the HiRISE study's LSM). Centre weighting resolves fine relief that a "
        "uniform template averages away.", minimum=0.0)
    sift: bool = parameter(_default("use_sift"), "Detect SIFT seed matches (besides Förstner "
                           "corners and --rectify's).")
    workers: int = workers_parameter()

    def matcher_options(self) -> dict:
        """Keywords of :func:`demtool.match.match` (besides images, seeds and range)."""
        values = self.as_dict()
        values["use_sift"] = values.pop("sift")
        del values["workers"]
        return values
