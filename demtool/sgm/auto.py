"""The choices of the default cost "auto" (issue 26): pure functions on disparity maps.

"auto" matches with HMI first (Hirschmüller 2008), then:

* on images whose pixel noise is small (:data:`FINE_NOISE_MAX`), near depth
  discontinuities (:func:`discontinuity_zone`), with census codes compared pixel by
  pixel (no window sum, :data:`FINE_CENSUS`: CNES Pandora's sample pipeline, census 5×5
  and P1 = 8) — the sharpest depth edges, so the fewest foreground-fattened pixels in
  occlusions — averaged with HMI where the two agree within a pixel (:func:`blend`),
  unless it is left–right consistent on markedly fewer pixels than HMI
  (:func:`prefer_fine`); elsewhere (and on images without discontinuities) the choice
  below;
* else (noisy or weakly textured images, where single census bits flip with the noise)
  with census summed over a window, which replaces HMI where HMI fails
  (:func:`prefer_census`) or confirms the HMI pixels it agrees with (:func:`agreement`);
  and with the absolute difference of the images' horizontal gradients (OpenCV
  StereoSGBM's Sobel prefilter: no offset, a gain only scales it), which replaces both
  where it is left–right consistent on more pixels than either (:func:`prefer_gradient`:
  a weakly textured surface in front of a textured one, whose texture census and HMI
  drag over the weak surface's borders);
* where HMI and census agree ("hmi+census"), near its depth edges
  (:func:`depth_edge_zone`) with census codes compared pixel by pixel with Pandora's
  penalties, left–right checked against a matching from the right image
  (:func:`cross_check`, Pandora's "accurate" cross-checking): the windowed costs fatten
  a foreground over up to about 10 px of the background beside it, and the check from
  one cost volume passes part of those pixels.

The thresholds were chosen by leave-one-out over the pairs of ``bench/stereo_accuracy.py``
(the five Middlebury pairs, six generated weak-texture and five plank pairs; range
0 … ndisp as a user gives it); the numbers are in the comments of each constant.
"""

from __future__ import annotations

import numpy as np

from demtool.logs import get_logger
from demtool.sgm import cost as costs
from demtool.sgm.extremes import box_max, box_min
from demtool.sgm.noise import noise_sigma, p2_kappa
from demtool.sgm.passes import (
    COST_DEFAULTS,
    CostDefaults,
    ad_pixel_cost,
    census_cost,
    census_fallback,
    filter_pass,
    match_cost,
    pixel_pass,
    support_radius,
)

log = get_logger(__name__)


# "auto": census replaces HMI where its left–right-consistent fraction is higher by more
# than this (chosen by leave-one-out over the five Middlebury pairs, the six weak-texture
# and five plank pairs of bench/, range 0 … ndisp: 0.060–0.065 in 14 of 16 folds; LOO mean
# bad-2 4.95 % against about 6.5 % for the better fixed cost, whose LOO fold on the plank
# where HMI fails picks HMI, issue 26), or where HMI leaves this much more of the image at
# a range bound than census does
AUTO_LR_MARGIN = 0.06
AUTO_BOUND_MARGIN = 0.05
# "auto" where HMI is kept: when census agrees (within 1 px) on at least this share of
# HMI's left–right-consistent pixels, only the HMI disparities both costs agree on are
# kept and the rest is filled (bad-2 mean over the 16 pairs, weak ones at half size,
# 4.22 % against 4.35 % with HMI alone there, census 4.74 %); below it (one pair, plank5:
# 74 %, census failing there) HMI alone.  Chosen on the same 16 pairs (any value in
# 0.74 … 0.84 separates them alike; not leave-one-out: plank5 is the only pair below).
AUTO_AGREEMENT = 0.80
# Census codes compared pixel by pixel (window 1): P1 is Pandora's (census 5×5 costs
# 0 … 24); P2 = 64 with the adaptive P2 (bad-2 mean over the five Middlebury pairs 2.77 %
# against 2.85 % with Pandora's 32; leave-one-out picks 64 in 4 of the 5 folds).
FINE_CENSUS = CostDefaults(window=1, p1=8, p2=64)
# Pixel census is used where the guide image's noise σ (Immerkær, grey levels of the
# 0 … 255 stretch, :func:`demtool.sgm.noise.noise_sigma`) is at most this.  The pairs
# fall in two groups: Middlebury 1.2 … 3.7 (pixel census better on all five: bad-2 −0.3
# to −1.5 points), the planks 6.9 … 10.4 and the weak-texture pairs 19 … 30 (pixel
# census worse on all but plank3, by up to 36 points where single bits flip with the
# noise).  5 is the middle of the gap; a threshold chosen on any 15 of the 16 pairs
# (anywhere in the gap around the held-out one) makes the same choice on the 16th.
FINE_NOISE_MAX = 5.0
# Near depth edges of a "hmi+census" result (:func:`depth_edge_zone`): census codes
# compared pixel by pixel with CNES Pandora's sample penalties (P1 8, P2 32, constant),
# left–right checked against a matching from the right image (:func:`cross_check`).
# On the six weak-texture pairs, the only ones of the 16 that reach "hmi+census",
# bad-2 (%) weak1 … weak6 0.00 / 1.82 / 2.06 / 0.03 / 4.40 / 0.01 without it, 0.00 /
# 1.30 / 1.45 / 0.03 / 3.38 / 0.01 with it; with the check from one cost volume
# instead weak2 1.40, weak3 1.58 (Pandora with interpolation: 1.32, 1.52).
EDGE_CENSUS = CostDefaults(window=1, p1=8, p2=32)
# The zone: pixels whose (2·radius + 1)² neighbourhood holds disparities more than
# ``jump`` px apart.  Chosen by leave-one-out over those six pairs on radius 3 … 16 ×
# jump 2 … 10 (19 settings): 12 / 6 in 5 of the 6 folds (16 / 8 in weak5's, bad-2 3.54
# there instead of 3.38); smaller jumps take the smooth pairs' slopes for edges (weak4
# 0.30 with 12 / 2), a jump of 10 misses the pairs' 5 … 10 px steps.
EDGE_ZONE_RADIUS = 12  # px
EDGE_ZONE_JUMP = 6.0  # px
# The low-noise choice (:func:`blend_fine`) takes the pixel census only near depth
# discontinuities (:func:`discontinuity_zone`: a jump of more than this between pixels
# at most 4 px apart) and the windowed choice elsewhere; an image without discontinuities
# (orbital terrain) keeps the windowed choice.  The census deciding everywhere made
# `synth --sensor frame` DEMs worse than the previous default (seed 0: RMSE 0.558 m
# against 0.439 m; a 4-view block's pairs up to 43 % worse); with the zone, seeds 0 / 3
# / 7 0.474 / 0.759 / 0.466 m against 0.439 / 0.800 / 0.443, the block fused 0.241 m
# against 0.239 m.  Chosen on seed 0 and the five Middlebury pairs (jump 2: Middlebury
# met, seed 0 0.484 m; 3: met, 0.458 m with filling elsewhere; a 3 × 3 jump lost teddy's
# occluded pixels to Pandora).
FINE_EDGE_JUMP = 3.0  # px


def full_range(valid: np.ndarray, min_disparity: int, num_disparities: int) -> np.ndarray:
    """``valid`` where every disparity of the range lands inside the right image
    (x − d in 0 … W − 1 for all d): there each cost could match."""
    width = valid.shape[1]
    columns = np.arange(width)
    inside = ((columns - (min_disparity + num_disparities - 1) >= 0)
              & (columns - min_disparity <= width - 1))
    return valid & inside[None, :]


def consistent_fraction(disparity: np.ndarray, valid: np.ndarray) -> float:
    """Fraction of the valid pixels with a disparity (after the left–right check)."""
    return np.count_nonzero(np.isfinite(disparity) & valid) / max(int(valid.sum()), 1)


def bound_fraction(disparity: np.ndarray, valid: np.ndarray, min_disparity: int,
                   num_disparities: int) -> float:
    """Fraction of the valid pixels whose disparity is within 0.5 px of a range bound."""
    high = min_disparity + num_disparities - 1
    with np.errstate(invalid="ignore"):
        at = (disparity < min_disparity + 0.5) | (disparity > high - 0.5)
    return float(np.count_nonzero(at & valid)) / max(int(valid.sum()), 1)


def prefer_census(hmi: np.ndarray, census: np.ndarray, valid: np.ndarray,
                  min_disparity: int, num_disparities: int) -> str:
    """Why census should replace HMI ("" when it should not).

    HMI fails on weak texture by settling on a wrong disparity over large areas (a
    joint histogram that never sharpens), which the left–right check partly exposes:
    census then passes it on markedly more pixels (:data:`AUTO_LR_MARGIN`), or HMI
    leaves markedly more pixels at a range bound (:data:`AUTO_BOUND_MARGIN`).
    """
    lr_hmi = consistent_fraction(hmi, valid)
    lr_census = consistent_fraction(census, valid)
    if lr_census - lr_hmi > AUTO_LR_MARGIN:
        return (f"left-right consistent {100 * lr_census:.1f} % of the pixels against "
                f"{100 * lr_hmi:.1f} % with HMI")
    bound_hmi = bound_fraction(hmi, valid, min_disparity, num_disparities)
    bound_census = bound_fraction(census, valid, min_disparity, num_disparities)
    if bound_hmi - bound_census > AUTO_BOUND_MARGIN:
        return (f"HMI leaves {100 * bound_hmi:.1f} % of the pixels at a bound of the "
                f"range, census {100 * bound_census:.1f} %")
    return ""


def prefer_fine(fine: np.ndarray, hmi: np.ndarray, valid: np.ndarray) -> str:
    """Why the pixel census should not be used on a low-noise image ("" when it should).

    Where it is left–right consistent on :data:`AUTO_LR_MARGIN` fewer pixels than HMI,
    its matches are unreliable (texture too weak for single pixels).
    """
    lr_fine = consistent_fraction(fine, valid)
    lr_hmi = consistent_fraction(hmi, valid)
    if lr_hmi - lr_fine > AUTO_LR_MARGIN:
        return (f"pixel census left-right consistent on {100 * lr_fine:.1f} % of the "
                f"pixels, HMI on {100 * lr_hmi:.1f} %")
    return ""


def prefer_gradient(gradient: np.ndarray, hmi: np.ndarray, census: np.ndarray,
                    valid: np.ndarray) -> str:
    """Why the gradient cost should replace HMI and census ("" when it should not): it
    is left–right consistent on more of the ``valid`` pixels than both (pass
    :func:`full_range`: where the search range leaves the right image, the costs fail
    alike and the count says nothing about them).

    No margin: of the 11 pairs of the benchmark that reach this choice (planks and
    weak-texture pairs) it is more consistent on two (plank1 +2.9 points, bad-2 8.1 %
    against 13.4 %; plank2 +9.2, 6.3 % against 11.2 %) and less on every other by 1.7
    points or more, so a margin chosen on any 10 makes the same choice on the 11th.
    """
    lr_gradient = consistent_fraction(gradient, valid)
    lr_best = max(consistent_fraction(hmi, valid), consistent_fraction(census, valid))
    if lr_gradient > lr_best:
        return (f"gradient difference left-right consistent on {100 * lr_gradient:.1f} % "
                f"of the pixels, HMI and census on at most {100 * lr_best:.1f} %")
    return ""


def agreement(first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, float]:
    """Pixels where both maps have disparities within 1 px, and their share of the first
    map's disparities."""
    both = np.isfinite(first) & np.isfinite(second)
    with np.errstate(invalid="ignore"):
        agreed = both & (np.abs(first - second) <= 1.0)
    return agreed, float(agreed.sum()) / max(int(np.isfinite(first).sum()), 1)


def blend(fine: np.ndarray, hmi: np.ndarray) -> np.ndarray:
    """The pixel-census disparities, averaged with HMI's where the two agree within 1 px.

    Two independent sub-pixel estimates: the mean has less noise (Middlebury MAE −6 to
    −13 % against the census alone; on tsukuba's integer-valued truth the census alone is
    24 % worse than HMI, the mean 9 %); where they disagree the census decides.
    """
    agreed, _ = agreement(fine, hmi)
    return np.where(agreed, 0.5 * (fine + hmi), fine).astype(np.float32)


def discontinuity_zone(disparity: np.ndarray, radius: int = EDGE_ZONE_RADIUS,
                       jump: float = FINE_EDGE_JUMP) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` px of a depth discontinuity — a 5 × 5
    neighbourhood whose finite disparities span more than ``jump`` px.  A jump between
    pixels at most 4 px apart, not a range over the zone: a terrain slope (orbital stereo
    at B/H 0.3 on a 40° crater wall changes the disparity by ~0.25 px per pixel) is not
    an edge, an object's border is.  (The window extremes: :mod:`demtool.sgm.extremes`,
    equal to scipy.ndimage's maximum/minimum filters.)"""
    finite = np.isfinite(disparity)
    high = box_max(np.where(finite, disparity, -np.inf), 2)
    low = box_min(np.where(finite, disparity, np.inf), 2)
    with np.errstate(invalid="ignore"):
        edge = np.isfinite(high) & np.isfinite(low) & (high - low > jump)
    if not edge.any():  # terrain: no zone
        return edge
    return box_max(edge, radius) > 0


def blend_fine(fine: tuple, hmi: tuple, zone: np.ndarray, base: tuple) -> tuple:
    """(disparity, confidence, occluded) of the low-noise choice: near depth
    discontinuities (``zone``, where a window cost fattens a foreground) the pixel census,
    averaged with HMI where the two agree within 1 px (:func:`blend`); elsewhere ``base``,
    the windowed costs' choice (on smooth ground the single-pixel costs are the noisier,
    and on a weak plank HMI fails: the windowed choice handles both)."""
    agreed, _ = agreement(fine[0], hmi[0])
    mean = (0.5 * (fine[0] + hmi[0])).astype(np.float32)
    return tuple(np.where(zone, np.where(agreed, m, f), b).astype(f.dtype)
                 for m, f, b in zip((mean, fine[1], fine[2]), fine, base, strict=True))


def depth_edge_zone(disparity: np.ndarray, radius: int = EDGE_ZONE_RADIUS,
                    jump: float = EDGE_ZONE_JUMP) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` px (a square) of a depth edge, i.e. whose
    neighbourhood holds finite disparities more than ``jump`` px apart (NaN ignored)."""
    finite = np.isfinite(disparity)
    high = box_max(np.where(finite, disparity, -np.inf), radius)
    low = box_min(np.where(finite, disparity, np.inf), radius)
    with np.errstate(invalid="ignore"):
        return np.isfinite(high) & np.isfinite(low) & (high - low > jump)


def cross_check(left: np.ndarray, confidence: np.ndarray, right: np.ndarray,
                threshold: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left–right check of two independently matched maps (CNES Pandora's
    ``cross_checking_accurate``, ``pandora/validation/validation.py``).

    Parameters
    ----------
    left : (H, W) float32, px
        Disparities of the left pixels, ``x_right = x − d``; NaN = none.
    confidence : (H, W) float32
        Their confidence (:class:`demtool.sgm.matcher.SGMResult`).
    right : (H, W) float32, px
        Disparities of the right pixels from a matching with the right image as the
        reference, ``x_left = x + d``; NaN = none.
    threshold : float
        Largest |d_left(x) − d_right(rint(x − d_left(x)))| kept, px.

    Returns
    -------
    disparity, confidence : (H, W) float32, NaN where the check fails
    occluded : (H, W) bool, the failed pixels whose match in the right image has the
        larger disparity (the right view sees something nearer there)
    """
    width = left.shape[1]
    with np.errstate(invalid="ignore"):
        matched = np.rint(np.arange(width)[None, :] - left)
        inside = np.isfinite(left) & (matched >= 0) & (matched < width)
        other = np.take_along_axis(right, np.where(inside, matched, 0).astype(np.intp), axis=1)
        consistent = inside & (np.abs(other - left) <= threshold)
        occluded = inside & ~consistent & (other > left)
    nan = np.float32(np.nan)
    return (np.where(consistent, left, nan).astype(np.float32),
            np.where(consistent, confidence, nan).astype(np.float32), occluded)


def mirrored(images: dict) -> dict:
    """The ``left``/``right`` images and ``left_valid``/``right_valid`` masks of
    ``images`` swapped and mirrored left–right: matched, they give the right image's
    disparities (mirrored), ``x_left = x + d``."""
    swap = {"left": "right", "right": "left", "left_valid": "right_valid",
            "right_valid": "left_valid"}
    return {key: np.ascontiguousarray(images[other][:, ::-1]) for key, other in swap.items()}


def at_depth_edges(zone: np.ndarray, base: tuple, sharp: tuple) -> tuple:
    """(disparity, confidence, occluded) of ``sharp`` inside ``zone``, of ``base``
    elsewhere (each a triple of (H, W) arrays)."""
    return tuple(np.where(zone, s, b) for b, s in zip(base, sharp, strict=True))


def share(mask: np.ndarray, valid: np.ndarray) -> float:
    """Fraction of the ``valid`` pixels in ``mask``, rounded to 4 decimals."""
    return round(float(np.count_nonzero(mask & valid)) / max(int(valid.sum()), 1), 4)


def choose(hmi, *, window, given, cost_window, match, filters, fractions, pixel_census=True,
           replaced=None):
    """The choices of cost "auto" after HMI (:mod:`demtool.sgm.auto`; ``pixel_census``
    False: the windowed choice alone).  ``hmi``: HMI's filtered (disparity, confidence,
    occluded), ``window`` its cost window; ``replaced``: (H, W) bool, the pixels whose
    result the caller replaces (a pass used only there is skipped).  Returns the chosen
    triple and its cost's support radius (:func:`demtool.sgm.edges.snap_edges`); the
    choice goes to ``fractions``."""
    valid, guide = match["left_valid"], match["guide"]
    census_shape = match["census_shape"]
    fractions["noise_sigma"] = round(noise := noise_sigma(guide, valid), 2)
    zone = (discontinuity_zone(hmi[0])
            if pixel_census and noise <= FINE_NOISE_MAX else None)
    if zone is not None and zone.any():  # no discontinuity (terrain): nothing to sharpen
        # the pair's census codes, shared by the pixel census, the windowed census and
        # the edge census from the left image (one transform instead of three)
        with match["common"]["timer"].measure("prepare"):
            codes = census_cost(*(match[k] for k in ("left", "right", "left_valid",
                                                     "right_valid", "census_shape",
                                                     "workers")))
        match = holding(dict(match, census_codes=codes), (codes.left, codes.right))
        fine = filter_pass(*census_fallback(cost_window, *given, holding(match, hmi),
                                            FINE_CENSUS), **filters)
        if not (why_not := prefer_fine(fine[0], hmi[0], valid)):
            log.info("cost auto: pixel census near depth discontinuities (noise σ %.1f)", noise)
            base, radius = choose(hmi, window=window, given=given, cost_window=cost_window,
                                  match=holding(match, fine), filters=filters,
                                  fractions=fractions, pixel_census=False, replaced=zone)
            fractions.update(cost_used=f"census+{fractions.get('cost_used', 'hmi')}",
                             edge_census=share(zone, valid))
            window = FINE_CENSUS.window if cost_window is None else int(cost_window)
            return (blend_fine(fine, hmi, zone, base),
                    max(radius, support_radius("census", window, census_shape)))
        log.info("cost auto: no pixel census (%s)", why_not)
        fractions["cost_reason"] = why_not
    other = filter_pass(*census_fallback(cost_window, *given, holding(match, hmi)), **filters)
    gradient = filter_pass(*gradient_pass(cost_window, given, holding(match, hmi, other)),
                           **filters)
    reason = prefer_gradient(gradient[0], hmi[0], other[0], full_range(
        valid, match["min_disparity"], match["num_disparities"]))
    if reason:
        log.info("cost auto: horizontal-gradient difference instead of HMI and census (%s)",
                 reason)
        fractions.update(cost_used="gradient", cost_reason=reason)
        gradient_window = COST_DEFAULTS["ad"].window if cost_window is None else cost_window
        return gradient, support_radius("ad", int(gradient_window), census_shape)
    del gradient  # not chosen: the windowed choice's passes run without it
    return windowed_choice(hmi, other, window=window, cost_window=cost_window, match=match,
                           fractions=fractions, filters=filters, replaced=replaced)


def holding(match: dict, *results: tuple) -> dict:
    """``match`` for a pass during which the (disparity, confidence, occluded)
    ``results`` of earlier passes are held: their bytes count against the memory budget
    (:func:`demtool.sgm.strips.match_pass`)."""
    held = sum(array.nbytes for result in results for array in result)
    common = match["common"]
    return dict(match, common=dict(common, held_bytes=common.get("held_bytes", 0) + held))


def gradient_pass(cost_window, given, match):
    """Absolute difference of the images' horizontal Sobel gradients, with the "ad"
    defaults (OpenCV StereoSGBM's prefilter; an offset cancels, a gain scales)."""
    def gradient(side):
        valid = match[f"{side}_valid"]
        return costs.horizontal_sobel(costs.fill_invalid(match[side], valid), valid)

    defaults = COST_DEFAULTS["ad"]
    p1, p2 = (d if g is None else g for g, d in zip(given, (defaults.p1, defaults.p2),
                                                     strict=True))
    left_valid, right_valid = match["left_valid"], match["right_valid"]
    with match["common"]["timer"].measure("prepare"):
        # the float gradient images are dropped before the pass: only their 8-bit
        # levels (cost and guide) are held while S is (2048²: 32 MB less)
        left, right = gradient("left"), gradient("right")
        pixel_cost = ad_pixel_cost(left, right, left_valid, right_valid)
        guide = costs.quantize(left, left_valid, 256)
        del left, right
    common = dict(match["common"], p1=p1, p2=max(p1, p2))
    if common["p2_kappa"]:
        common["p2_kappa"] = p2_kappa(guide, left_valid)
    window = defaults.window if cost_window is None else int(cost_window)
    return pixel_pass(pixel_cost, left_valid=left_valid, right_valid=right_valid,
                      guide=guide, min_disparity=match["min_disparity"],
                      num_disparities=match["num_disparities"], window=window,
                      common=common, final=match["final"], levels=match["levels"])


def windowed_choice(hmi, other, *, window, cost_window, match, fractions, filters,
                    replaced=None):
    """HMI, census summed over a window, or the HMI pixels census confirms (near depth
    edges the pixel census, :func:`edge_census`, unless all of them are ``replaced``:
    the low-noise choice's depth-discontinuity zone often covers them, on tsukuba
    entirely, sparing its two passes)."""
    valid, census_shape = match["left_valid"], match["census_shape"]
    hmi_radius = support_radius("hmi", window, census_shape)
    reason = prefer_census(hmi[0], other[0], valid, match["min_disparity"],
                           match["num_disparities"])
    fractions["cost_used"] = "census" if reason else "hmi"
    if reason:
        log.info("cost auto: census instead of HMI (%s)", reason)
        fractions["cost_reason"] = reason
        window = COST_DEFAULTS["census"].window if cost_window is None else int(cost_window)
        return other, support_radius("census", window, census_shape)
    agreed, agreed_share = agreement(hmi[0], other[0])
    if agreed_share < AUTO_AGREEMENT:
        log.info("cost auto: HMI kept (census agrees on only %.1f %% of its matches)",
                 100 * agreed_share)
        return hmi, hmi_radius
    log.info("cost auto: HMI and census agree on %.1f %% of HMI's matches; keeping those, "
             "the rest is filled", 100 * agreed_share)
    fractions["cost_used"] = "hmi+census"
    disparity, confidence = (np.where(agreed, a, np.float32(np.nan)).astype(np.float32)
                             for a in (hmi[0], np.minimum(hmi[1], other[1])))
    result, zone = (disparity, confidence, hmi[2] | other[2]), depth_edge_zone(disparity)
    if zone.any():  # where the windowed costs fatten a foreground
        fractions["edge_census"] = share(zone, valid)
        if replaced is not None and not (zone & ~replaced).any():
            log.info("cost auto: no pixel census near depth edges (the pixel census near "
                     "depth discontinuities replaces them all)")
            return result, hmi_radius
        log.info("cost auto: pixel census near depth edges (%.1f %% of the pixels)",
                 100 * fractions["edge_census"])
        result = at_depth_edges(zone, result,
                                edge_census(holding(match, hmi, other, result), filters))
    return result, hmi_radius


def edge_census(match, filters):
    """:data:`EDGE_CENSUS` from the left and the right image, cross-checked
    (:func:`cross_check`; not with ``lr_check`` off).  P2 constant: no guide."""
    census = EDGE_CENSUS

    def options(match):
        return dict(match, window=census.window, common=dict(
            match["common"], p1=census.p1, p2=census.p2, p2_kappa=0),
            final=dict(match["final"], lr_threshold=None))

    left = filter_pass(*match_cost("census", **options(match)), **filters)
    if match["final"]["lr_threshold"] is None:
        return left
    right = filter_pass(*match_cost("census", **dict(options(holding(match, left)),
                                                     **mirrored(match), census_codes=None)),
                        **filters)
    return cross_check(left[0], left[1], right[0][:, ::-1],
                              match["final"]["lr_threshold"])
