"""Parameters of ``demtool rectify`` (defaults: those of :func:`demtool.rectify.rectify_pair`).

Beside the single-module core :mod:`demtool.rectify`.  The command's options are
generated from these fields; each default is read from the core function's signature.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.parameters import Parameters, core_default, parameter, seed_parameter
from demtool.rectify import rectify_pair


def _default(name: str):
    return core_default(rectify_pair, name)


@dataclass(frozen=True)
class RectifyParams(Parameters):
    """Every option of ``demtool rectify`` except its files (see
    :func:`demtool.rectify.rectify_pair`)."""

    min_matches: int = parameter(_default("min_matches"), "Fewest SIFT matches (and final "
                                 "control points) accepted.", minimum=8)
    ratio: float = parameter(_default("ratio"), "Lowe's ratio-test threshold.", minimum=0.0,
                             maximum=1.0, min_open=True)
    ransac_threshold: float = parameter(_default("ransac_threshold"), "Inlier threshold of "
                                        "the robust F (Sampson distance), px.", minimum=0.0,
                                        min_open=True)
    max_vertical_residual: float = parameter(
        _default("max_vertical_residual"), "Drop control points whose rectified rows differ "
        "by more (px), re-estimate.", minimum=0.0, min_open=True)
    shear: bool = parameter(_default("shear"), "Loop-Zhang shear keeping rectified pixels "
                            "square.")
    disparity_margin: float = parameter(
        _default("disparity_margin"), "Pixels added to each side of the inliers' disparity "
        "range (plus 10 % of its span).", minimum=0.0)
    max_features: int = parameter(_default("max_features"), "SIFT keypoints kept per image, "
                                  "strongest first (0 = all).", minimum=0)
    contrast_threshold: float = parameter(
        _default("contrast_threshold"), "SIFT contrast threshold (lower: more keypoints).",
        minimum=0.0, min_open=True)
    seed: int = seed_parameter()
