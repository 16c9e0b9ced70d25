"""Parameters of ``demtool select`` (defaults: the core's, :mod:`demtool.select.core`).

Beside the single-module core :mod:`demtool.select.core`.  The command's options are
generated from these fields; each default is read from the core function's signature.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_defaults
from demtool.parameters import Parameters, parameter, seed_field, workers_field

# Read from the cores' source: the core imports the sensor models, which every command run
# with a preset naming [select] would import otherwise.
CORE = core_defaults("demtool.select.core:compare_with_target")
SIFT = core_defaults("demtool.imaging.features:detect_sift")


@dataclass(frozen=True)
class SelectParams(Parameters):
    """Every option of ``demtool select`` except its files and ROI."""

    min_matches: int = parameter(CORE["min_matches"], "Fewest ratio-test matches to keep "
                                 "an image (the study's 50).", minimum=8)
    min_inliers: int = parameter(CORE["min_inliers"], "Fewest matches agreeing with one "
                                 "fundamental matrix.", minimum=8)
    min_overlap: float = parameter(CORE["min_overlap"], "Smallest fraction of the ROI an "
                                   "image must cover (0 = no test).", minimum=0.0, maximum=1.0)
    ratio: float = parameter(CORE["ratio"], "Lowe's ratio-test threshold.", minimum=0.0,
                             maximum=1.0, min_open=True)
    ransac_threshold: float = parameter(CORE["ransac_threshold"], "Inlier threshold of the "
                                        "fundamental-matrix RANSAC, px.", minimum=0.0,
                                        min_open=True)
    max_features: int = parameter(SIFT["max_features"], "SIFT keypoints "
                                  "kept per image, strongest first (0 = all).", minimum=0)
    contrast_threshold: float = parameter(
        SIFT["contrast_threshold"], "SIFT contrast threshold (lower: "
        "more keypoints).", minimum=0.0, min_open=True)
    rank: bool = parameter(False, "Order the selected images by the ranking score.",
                           flag="--rank")
    workers: int = workers_field()
    no_cache: bool = parameter(False, "Do not read or write the feature cache.",
                               flag="--no-cache")
    seed: int = seed_field()
