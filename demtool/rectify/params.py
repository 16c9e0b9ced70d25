"""Parameters of ``demtool rectify`` (defaults: those of :func:`demtool.rectify.core.rectify_pair`).

Beside the single-module core :mod:`demtool.rectify.core`.  The command's options are
generated from these fields; each default is read from the core function's signature.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_defaults
from demtool.parameters import Parameters, parameter, seed_field

# Read from the cores' source: `demtool rectify --help` does not load numba.
CORE = core_defaults("demtool.rectify.core:rectify_pair")
CALIBRATED = core_defaults("demtool.rectify.calibrated:rectify_sensors")


@dataclass(frozen=True)
class RectifyParams(Parameters):
    """Every option of ``demtool rectify`` except its files (see
    :func:`demtool.rectify.core.rectify_pair`)."""

    min_matches: int = parameter(CORE["min_matches"], "Fewest SIFT matches (and final "
                                 "control points) accepted.", minimum=8)
    ratio: float = parameter(CORE["ratio"], "Lowe's ratio-test threshold.", minimum=0.0,
                             maximum=1.0, min_open=True)
    ransac_threshold: float = parameter(CORE["ransac_threshold"], "Inlier threshold of "
                                        "the robust F (Sampson distance), px.", minimum=0.0,
                                        min_open=True)
    max_vertical_residual: float = parameter(
        CORE["max_vertical_residual"], "Drop control points whose rectified rows differ "
        "by more (px), re-estimate.", minimum=0.0, min_open=True)
    shear: bool = parameter(CORE["shear"], "Loop-Zhang shear keeping rectified pixels "
                            "square.")
    disparity_margin: float = parameter(
        CORE["disparity_margin"], "Least pixels added to each side of the inliers' robust "
        "disparity range (1st-99th percentile; 10 % of its span when more).", minimum=0.0)
    disparity_range: tuple[float, float] | None = parameter(
        None, "Disparity search range to record, px (default: from the control points).",
        metavar="MIN MAX", cli=False)
    max_features: int = parameter(CORE["max_features"], "SIFT keypoints kept per image, "
                                  "strongest first (0 = all).", minimum=0)
    contrast_threshold: float = parameter(
        CORE["contrast_threshold"], "SIFT contrast threshold (lower: more keypoints).",
        minimum=0.0, min_open=True)
    systematic_residual: float = parameter(
        CALIBRATED["systematic_px"], "With sensor models: RMS vertical residual of the SIFT "
        "matches (px) above which the right camera's pointing is corrected.", minimum=0.0)
    max_pointing_correction: float = parameter(
        CALIBRATED["max_pointing_mrad"], "With sensor models: largest pointing correction "
        "accepted, mrad (more: the SPICE is off, run bundle).", minimum=0.0, min_open=True)
    seed: int = seed_field()

    def check(self) -> None:
        super().check()
        given = self.disparity_range
        if given is not None and not (len(given) == 2 and given[0] < given[1]):
            self.fail("disparity_range", f"must be MIN MAX with MIN < MAX, got "
                      f"{' '.join(f'{v:g}' for v in given)}")
