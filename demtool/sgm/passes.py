"""One SGM pass of a cost over the whole image, and the filters after it.

:func:`match_cost` computes the raw disparity and confidence of one cost ("census",
"ad", "mi" iterated at full resolution, or the hierarchical "hmi" schedule,
Hirschmüller 2008 §3.1.4); :func:`filter_pass` and :func:`fill_pass` are the
uniqueness, speckle and median filters and the invalid-pixel fill after it.  The
matcher (:func:`demtool.sgm.matcher.sgm`) and the choices of the cost "auto"
(:mod:`demtool.sgm.auto`) chain them.

References
----------
Hirschmüller, H. (2008), Stereo processing by semiglobal matching and mutual
information, IEEE TPAMI 30(2), 328–341.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from demtool.errors import InputError
from demtool.logs import get_logger
from demtool.sgm import cost as costs
from demtool.sgm.disparity import OCCLUDED, matchable, median_filter, remove_speckles
from demtool.sgm.fill import MATCHED, fill_classified
from demtool.sgm.pyramid import MIN_LEVEL_SIZE, downsample, mi_levels, upsample_disparity
from demtool.sgm.strips import PhaseTimer, match_pass

log = get_logger(__name__)


class CostDefaults(NamedTuple):
    """Tuned defaults of one cost: window side and penalties (cost units)."""

    window: int
    p1: int
    p2: int


# Tuned with bench/stereo_accuracy.py (the synthetic scene, the weak-texture "hard" pair
# and Middlebury tsukuba, venus, cones, teddy) with the adaptive P2 on.  Larger penalties
# help the noisy weak-texture pair (MI 40/400 → 50/700: hard bad-2 0.31 % → 0.07 %,
# density 71 % → 89 %; census 60/600 → 70/1200: 0.88 % → 0.65 %) until bad-2 on
# Middlebury rises above OpenCV SGBM's (MI venus needs P1 ≥ 50, tsukuba P2 ≤ ~800), and a
# larger P1 locks the sub-pixel fit to integers (census P1 = 200: −0.15 px bias at a
# quarter-pixel shift).  MI pixel costs are 0..64 (8 per nat), census 0..24 (5×5 bits),
# absolute difference 0..24 grey levels, all summed over the window.
COST_DEFAULTS: dict[str, CostDefaults] = {
    "census": CostDefaults(window=5, p1=70, p2=1200),
    "mi": CostDefaults(window=3, p1=50, p2=700),
    "ad": CostDefaults(window=5, p1=60, p2=600),
}
MI_SIGMA = 1.0  # Parzen window, grey levels
AD_TRUNCATION = 24  # grey levels (of 256)
UNMATCHED_FRACTION = 0.35  # cost of a match outside/NaN in the right image, of the maximum




def filter_pass(disparity: np.ndarray, confidence: np.ndarray, *, speckle_size: int,
            speckle_range: float, median: int, timer: PhaseTimer, uniqueness: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniqueness, speckles and median; returns the disparity, the confidence (NaN where
    invalid) and the mask of the pixels the left–right check found occluded."""
    with timer.measure("postprocess"):
        occluded = confidence == OCCLUDED
        if uniqueness > 0:
            disparity = np.where(confidence >= uniqueness, disparity, np.float32(np.nan))
        if speckle_size > 0:
            disparity = remove_speckles(disparity, max_size=speckle_size,
                                        max_difference=speckle_range)
        if median > 1:
            disparity = median_filter(disparity, median)
        confidence = np.where(np.isfinite(disparity), confidence, np.float32(np.nan))
    return disparity, confidence.astype(np.float32), occluded


def fill_pass(disparity: np.ndarray, confidence: np.ndarray, occluded: np.ndarray, *,
          fill_mask: np.ndarray | None, right_valid: np.ndarray, timer: PhaseTimer
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The invalid-pixel fill (with ``fill_mask``) and the classes of the pixels.

    Filled pixels get confidence 0; those whose match falls outside the right image or
    on one of its invalid pixels stay NaN.
    """
    if fill_mask is None:
        return disparity, confidence, None
    with timer.measure("postprocess"):
        before = np.isfinite(disparity)
        disparity, classes = fill_classified(disparity, occluded & ~before, fill_mask)
        disparity = matchable(disparity, right_valid)
        confidence = np.where(np.isfinite(disparity),
                              np.where(classes == MATCHED, confidence, np.float32(0.0)),
                              np.float32(np.nan))
    return disparity, confidence.astype(np.float32), classes


def postprocess(disparity: np.ndarray, confidence: np.ndarray, *, speckle_size: int,
                 speckle_range: float, median: int, timer: PhaseTimer, uniqueness: float = 0.0,
                 fill_mask: np.ndarray | None = None, right_valid: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Uniqueness, speckles, median, then (with ``fill_mask``) the invalid-pixel fill."""
    disparity, confidence, occluded = filter_pass(
        disparity, confidence, speckle_size=speckle_size, speckle_range=speckle_range,
        median=median, timer=timer, uniqueness=uniqueness)
    disparity, confidence, _ = fill_pass(disparity, confidence, occluded, fill_mask=fill_mask,
                                     right_valid=right_valid, timer=timer)
    return disparity, confidence


class NoMutualInformation(InputError):
    """The MI histogram has no valid pixel pairs (the census fallback takes over)."""


def census_fallback(cost_window, p1, p2, match, defaults=None):
    """Census matching with its own defaults (``defaults``, else :data:`COST_DEFAULTS`)
    where the caller gave none."""
    defaults = COST_DEFAULTS["census"] if defaults is None else defaults
    common = dict(match["common"], p1=defaults.p1 if p1 is None else p1,
                  p2=defaults.p2 if p2 is None else p2)
    if common["p1"] > common["p2"]:
        common["p2"] = common["p1"]
    window = defaults.window if cost_window is None else int(cost_window)
    return match_cost("census", window=window, **dict(match, common=common))


def support_radius(cost: str, window: int, census_shape: tuple[int, int]) -> int:
    """Half-width (px, along a row) of the image patch one pixel's cost sees: how far a
    textured foreground can fatten into its neighbour (:mod:`demtool.sgm.edges`);
    ``census_shape``: the census window's (rows, columns)."""
    radius = (window - 1) // 2
    if cost == "census":
        radius += census_shape[1] // 2
    return max(radius, 1)


def match_cost(cost, *, left, right, left_valid, right_valid, guide, left_range,
               min_disparity, num_disparities, window, census_shape, mi_iterations, seed,
               common, final, speckle, levels, workers, census_codes=None):
    """The raw disparity and confidence of one cost (before filters and fill);
    ``census_shape``: the census window's (rows, columns); ``census_codes``: the pair's
    census pixel cost when already computed (:func:`census_cost`)."""
    if cost in ("census", "ad"):
        with common["timer"].measure("prepare"):
            if cost == "ad":
                pixel_cost = ad_pixel_cost(left, right, left_valid, right_valid)
            elif census_codes is None:
                pixel_cost = census_cost(left, right, left_valid, right_valid, census_shape,
                                         workers)
            else:
                pixel_cost = census_codes
        return pixel_pass(pixel_cost, left_valid=left_valid, right_valid=right_valid,
                          guide=guide, min_disparity=min_disparity,
                          num_disparities=num_disparities, window=window, common=common,
                          final=final, levels=levels)
    return mutual_information_sgm(
        left, right, left_valid, right_valid, guide, cost=cost,
        min_disparity=min_disparity, num_disparities=num_disparities, window=window,
        mi_iterations=mi_iterations, seed=seed, common=common, final=final,
        speckle=speckle, levels=levels, left_range=left_range)


def census_cost(left, right, left_valid, right_valid, census_shape, workers
                ) -> costs.PixelCost:
    """Census pixel cost of the pair, invalid pixels filled (window ``census_shape``)."""
    return costs.census_pixel_cost(costs.fill_invalid(left, left_valid),
                                   costs.fill_invalid(right, right_valid), census_shape,
                                   workers=workers)


def ad_pixel_cost(left, right, left_valid, right_valid) -> costs.PixelCost:
    """Truncated absolute difference of the pair quantized to 256 levels over their
    joint robust range (:data:`AD_TRUNCATION`)."""
    value_range = costs.robust_range([left, right], [left_valid, right_valid])
    return costs.absolute_difference_pixel_cost(
        "ad", costs.quantize(left, left_valid, 256, value_range),
        costs.quantize(right, right_valid, 256, value_range), levels=256,
        truncation=AD_TRUNCATION)


def pixel_pass(pixel_cost, *, left_valid, right_valid, guide, min_disparity, num_disparities,
               window, common, final, levels):
    """The full-resolution SGM pass of a census or "ad" pixel cost; its raw disparity
    and confidence (the pass is recorded in ``levels``)."""
    disparity, confidence = match_pass(
        pixel_cost, left_valid, right_valid, guide, min_disparity=min_disparity,
        num_disparities=num_disparities, window=window, **common, **final)
    levels.append({"scale": 1, "cost": pixel_cost.name, "min_disparity": min_disparity,
                   "num_disparities": num_disparities,
                   "valid_fraction": float(np.isfinite(disparity).mean())})
    return disparity, confidence


def mutual_information_sgm(left, right, left_valid, right_valid, guide, *, cost, min_disparity,
                            num_disparities, window, mi_iterations, seed, common, final,
                            speckle, levels, left_range=None):
    """Iterated MI ("mi") or the hierarchical HMI schedule ("hmi").

    ``left_range``: the left image's robust range when already computed (full level).
    """
    timer: PhaseTimer = common["timer"]
    max_disparity = min_disparity + num_disparities - 1
    # the pyramid: (scale, left, right, valid masks, guide); scale 1 last
    pyramid = [(1, left, right, left_valid, right_valid, guide)]
    if cost == "hmi":
        scale = 1
        while scale < 16:
            _, image_l, image_r, valid_l, valid_r, _ = pyramid[0]
            if min(image_l.shape) // 2 < MIN_LEVEL_SIZE:
                break
            image_l, valid_l = downsample(image_l, valid_l)
            image_r, valid_r = downsample(image_r, valid_r)
            if not (valid_l.any() and valid_r.any()):
                break
            scale *= 2
            pyramid.insert(0, (scale, image_l, image_r, valid_l, valid_r,
                               costs.quantize(image_l, valid_l, 256)))
    previous = None
    for index in range(len(pyramid)):
        # each level is dropped once matched, the estimate once its MI table is made
        # (2048² × 128: about 40 MB less held during the full-resolution pass)
        scale, image_l, image_r, valid_l, valid_r, level_guide = pyramid[index]
        pyramid[index] = None
        with timer.measure("prepare"):
            n_levels = mi_levels(int(min(valid_l.sum(), valid_r.sum())))
            levels_l = costs.quantize(image_l, valid_l, n_levels,
                                      left_range if scale == 1 else None)
            levels_r = costs.quantize(image_r, valid_r, n_levels)
            lo = math.floor(min_disparity / scale) - (1 if scale > 1 else 0)
            hi = math.ceil(max_disparity / scale) + (1 if scale > 1 else 0)
            width = image_l.shape[1]
            lo, hi = max(lo, -(width - 2)), min(hi, width - 2)
            count = hi - lo + 1
            if previous is None:
                if cost == "hmi":
                    rng = np.random.default_rng(seed)
                    estimate = rng.integers(lo, hi + 1, size=image_l.shape).astype(np.float32)
                else:
                    estimate = np.full(image_l.shape, float(np.clip(0, lo, hi)), dtype=np.float32)
            else:
                estimate = upsample_disparity(previous, image_l.shape)
        iterations = mi_iterations if (cost == "mi" or index == 0) else 1
        last_level = scale == 1
        for iteration in range(iterations):
            with timer.measure("mi"):
                mi, pairs = costs.mutual_information_table(levels_l, levels_r, valid_l, valid_r,
                                                           estimate, levels=n_levels,
                                                           sigma=MI_SIGMA)
                if pairs == 0:
                    raise NoMutualInformation(
                        "no valid corresponding pixels for the MI histogram at 1/"
                        f"{scale} scale (disparities {lo} … {hi})")
                pixel_cost = costs.table_pixel_cost("mi", levels_l, levels_r,
                                                    costs.mi_cost_table(mi))
                estimate = previous = None
            final_pass = last_level and iteration == iterations - 1
            options = final if final_pass else dict(subpixel="none", lr_threshold=1.0)
            disparity, confidence = match_pass(
                pixel_cost, valid_l, valid_r, level_guide, min_disparity=lo,
                num_disparities=count, window=window, **common, **options)
            if not final_pass:
                disparity, _ = postprocess(disparity, confidence, speckle_size=speckle[0],
                                            speckle_range=speckle[1], median=3, timer=timer)
            levels.append({"scale": scale, "iteration": iteration + 1, "min_disparity": lo,
                           "num_disparities": count, "mi_levels": n_levels, "mi_pairs": pairs,
                           "valid_fraction": float(np.isfinite(disparity).mean())})
            log.debug("MI level 1/%d iteration %d: %d disparities, %.1f %% valid", scale,
                      iteration + 1, count, 100 * levels[-1]["valid_fraction"])
            estimate = disparity
        previous = estimate
    return disparity, confidence
