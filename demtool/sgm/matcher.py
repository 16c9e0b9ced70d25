"""Semi-global matching of a rectified pair: costs, strips, MI iterations and HMI pyramid.

:func:`sgm` is the stage's core (arrays in, arrays out).  Each SGM pass holds one
uint16 volume, the aggregated cost S; the matching cost is computed row by row inside
the sweeps (:mod:`demtool.sgm.aggregate`).  The down and up sweeps run in two threads
(the numba kernels release the GIL).  Only when S does not fit the memory budget is the
image cut into horizontal strips with an overlap.

References
----------
Hirschmüller, H. (2008), Stereo processing by semiglobal matching and mutual
information, IEEE TPAMI 30(2), 328–341.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from demtool.errors import InputError, ParameterError
from demtool.logs import get_logger
from demtool.sgm import auto as choice
from demtool.sgm import cost as costs
from demtool.sgm.auto import CostDefaults
from demtool.sgm.disparity import OCCLUDED, matchable, median_filter, remove_speckles
from demtool.sgm.edges import snap_edges
from demtool.sgm.fill import MATCHED, class_fractions, classify, fill_classified
from demtool.sgm.noise import (  # noqa: F401  (re-exported: part of this module's API)
    P2_KAPPA,
    P2_KAPPA_NOISE,
    noise_sigma,
    p2_kappa,
)
from demtool.sgm.pyramid import (  # noqa: F401  (mi_levels: part of this module's API)
    MI_LEVELS,
    MIN_LEVEL_SIZE,
    downsample,
    mi_levels,
    upsample_disparity,
)
from demtool.sgm.strips import (  # noqa: F401  (plan_strips: part of this module's API)
    PhaseTimer,
    available_cores,
    match_pass,
    plan_strips,
)

log = get_logger(__name__)

COSTS = ("auto", "hmi", "mi", "census", "ad")
CENSUS_WINDOWS = {"5x5": (5, 5), "9x7": (7, 9)}  # (rows, columns): 9 wide, 7 high


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


@dataclass(frozen=True)
class SGMResult:
    """What :func:`sgm` returns.

    Attributes
    ----------
    disparity : (H, W) float32
        Pixels in the left image's frame, ``x_right = x_left − d``; NaN = invalid.
    confidence : (H, W) float32
        0..1, (S₂ − S₁)/S₂ of the best and the best non-adjacent aggregated cost;
        0 where the disparity was filled in (``fill``), NaN where it is NaN.
    parameters : dict
        The resolved parameters (defaults filled in).
    timings : dict of str to float
        Seconds per phase, summed over strips and pyramid levels.
    levels : list of dict
        One entry per SGM pass (MI iteration or HMI level): scale, disparity range,
        valid fraction, number of pixel pairs in the MI histogram.
    classes : (H, W) uint8 or None
        What each pixel is (:mod:`demtool.sgm.fill`): 0 invalid, 1 matched (passed the
        left–right check and the filters), 2 filled occlusion, 3 filled mismatch, 4
        matched at a bound of the disparity range.
    fractions : dict of str to float
        The fraction of the valid left pixels in each class (``matched`` …) and of
        those whose disparity was moved back onto an image edge (``edge_moved``);
        ``cost_used``/``cost_reason`` and the guide image's ``noise_sigma`` (grey levels
        of its 0 … 255 stretch) when "auto" chose.
    """

    disparity: np.ndarray
    confidence: np.ndarray
    parameters: dict[str, Any]
    timings: dict[str, float] = field(default_factory=dict)
    levels: list[dict[str, Any]] = field(default_factory=list)
    classes: np.ndarray | None = None
    fractions: dict[str, Any] = field(default_factory=dict)


def _filter(disparity: np.ndarray, confidence: np.ndarray, *, speckle_size: int,
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


def _fill(disparity: np.ndarray, confidence: np.ndarray, occluded: np.ndarray, *,
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


def _postprocess(disparity: np.ndarray, confidence: np.ndarray, *, speckle_size: int,
                 speckle_range: float, median: int, timer: PhaseTimer, uniqueness: float = 0.0,
                 fill_mask: np.ndarray | None = None, right_valid: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Uniqueness, speckles, median, then (with ``fill_mask``) the invalid-pixel fill."""
    disparity, confidence, occluded = _filter(
        disparity, confidence, speckle_size=speckle_size, speckle_range=speckle_range,
        median=median, timer=timer, uniqueness=uniqueness)
    disparity, confidence, _ = _fill(disparity, confidence, occluded, fill_mask=fill_mask,
                                     right_valid=right_valid, timer=timer)
    return disparity, confidence


def _check_inputs(left: np.ndarray, right: np.ndarray, min_disparity: int,
                  num_disparities: int) -> None:
    if left.ndim != 2 or right.ndim != 2:
        raise InputError(f"images must be 2-D, got shapes {left.shape} and {right.shape}")
    if left.shape != right.shape:
        raise InputError(f"the rectified images differ in size: left {left.shape[1]}×"
                         f"{left.shape[0]}, right {right.shape[1]}×{right.shape[0]} "
                         "(width×height); rectify them onto one canvas")
    for name, image in (("left", left), ("right", right)):
        if not np.isfinite(image).any():
            raise InputError(f"the {name} image contains no valid (finite) pixel")
    width = left.shape[1]
    if num_disparities < 1:
        raise ParameterError(f"num_disparities must be at least 1, got {num_disparities}")
    max_disparity = min_disparity + num_disparities - 1
    if num_disparities >= width or max(abs(min_disparity), abs(max_disparity)) >= width:
        raise ParameterError(f"disparity range {min_disparity}..{max_disparity} is wider "
                             f"than the image ({width} px)")


def sgm(left: np.ndarray, right: np.ndarray, *, min_disparity: int, num_disparities: int,
        cost: str = "auto", census_window: str = "5x5", cost_window: int | None = None,
        paths: int = 8, p1: int | None = None, p2: int | None = None,
        adaptive_p2: bool = True, mi_iterations: int = 3, subpixel: str = "equiangular",
        lr_check: bool = True, lr_threshold: float = 1.0, speckle_size: int = 100,
        speckle_range: float = 2.0, median: int = 3, uniqueness: float = 0.0,
        fill: bool = True, workers: int = 0,
        max_memory_mb: float = 640.0, seed: int = 0) -> SGMResult:
    """Dense disparity of a rectified pair by semi-global matching (Hirschmüller 2008).

    Parameters
    ----------
    left, right : (H, W) float arrays
        The rectified images (any radiometric scale, e.g. 12-bit DN); NaN marks
        pixels outside the warped image, which never match and come out NaN.
    min_disparity, num_disparities : int
        Search range d = min_disparity .. min_disparity + num_disparities − 1 pixels,
        ``x_right = x_left − d``.
    cost : {"auto", "hmi", "mi", "census", "ad"}
        "auto" (the default): "hmi", then (:mod:`demtool.sgm.auto`) on images of
        little pixel noise census codes compared pixel by pixel, averaged with HMI
        where the two agree ("census+hmi"); on noisy or weakly textured images census
        summed over a window, which replaces HMI where HMI fails (census left–right
        consistent on markedly more pixels, or HMI pinned at a range bound), or else
        keeps the HMI pixels it agrees with ("hmi+census", the others filled), near whose
        depth edges a pixel census cross-checked against a matching from the right image
        replaces them; the choice is logged and returned in ``fractions["cost_used"]``.
        Any MI cost whose histogram finds no valid pixel pair falls back to census with
        a warning instead of failing.  "hmi": mutual information with the hierarchical
        schedule (1/16 → 1, the coarsest level iterated ``mi_iterations`` times from a
        random disparity, every finer level once from the coarser result;
        Hirschmüller 2008 §3.1.4);
        "mi": mutual information iterated ``mi_iterations`` times at full
        resolution from a zero disparity; "census": Hamming distance of census
        codes; "ad": truncated absolute difference.  Every cost is summed over a
        ``cost_window`` square.  With ``fill`` and ``lr_check``, depth edges are moved
        back onto the image's edges (:func:`demtool.sgm.edges.snap_edges`).
    census_window : {"5x5", "9x7"}
        Census window (width × height).
    cost_window : int, optional
        Odd side of the window the pixel cost is summed over (default per cost,
        :data:`COST_DEFAULTS`).
    paths : {8, 16}
    p1, p2 : int, optional
        Smoothness penalties in cost units (defaults per cost, :data:`COST_DEFAULTS`).
    adaptive_p2 : bool
        Lower P2 across intensity edges (P2·κ/|ΔI|, κ = ``P2_KAPPA`` grey levels).
    mi_iterations : int
        MI iterations ("mi": at full resolution; "hmi": at the coarsest level).
    subpixel : {"equiangular", "parabola", "none"}
    lr_check : bool
        Keep only pixels whose left and right disparities (both from one aggregated
        cost) agree within ``lr_threshold`` pixels.
    speckle_size : int
        Regions smaller than this (pixels) are removed (0 = off).
    speckle_range : float
        Largest disparity step inside a region, pixels.
    median : int
        Side of the NaN-aware median filter (1 = off).
    uniqueness : float
        Invalidate pixels whose confidence (S₂ − S₁)/S₂ is below this (0 = off;
        0.1 is OpenCV's ``uniquenessRatio=10``).
    fill : bool
        Fill the pixels left invalid (LR check, speckles, uniqueness) from the nearest
        valid disparities in 8 directions: occluded ones from the background that the
        right view hides, the others by the median (Hirschmüller 2008 §3.4,
        :func:`demtool.sgm.fill.fill_classified`); they get confidence 0 and their
        class in ``classes``.  Pixels invalid in the left image stay NaN.
    workers : int
        Threads (0 = all cores): two run the down and up sweeps of a strip; more match
        ``workers // 2`` strips at once.
    max_memory_mb : float
        Budget of S and the row buffers of the strips matched at once, MiB (beyond it
        the sweeps recompute their end rows: same result, ~13 % more CPU; issue 28).
    seed : int
        Seed of the random initial disparity of "hmi".

    Returns
    -------
    SGMResult

    Raises
    ------
    InputError
        Images of different sizes, not 2-D, or without a finite pixel.
    ParameterError
        A disparity range wider than the image, or bad option values.
    """
    left = np.asarray(left, dtype=np.float32)
    right = np.asarray(right, dtype=np.float32)
    _check_inputs(left, right, min_disparity, num_disparities)
    if cost not in COSTS:
        raise ParameterError(f"unknown cost {cost!r}: should be one of {', '.join(COSTS)}")
    if census_window not in CENSUS_WINDOWS:
        raise ParameterError(f"unknown census window {census_window!r}: should be one of "
                             + ", ".join(CENSUS_WINDOWS))
    defaults = COST_DEFAULTS["mi" if cost in ("hmi", "auto") else cost]
    given = (p1, p2)  # the caller's penalties (None: per cost)
    window = defaults.window if cost_window is None else int(cost_window)
    p1 = defaults.p1 if p1 is None else int(p1)
    p2 = defaults.p2 if p2 is None else int(p2)
    if window < 1 or window % 2 == 0:
        raise ParameterError(f"cost window must be an odd number ≥ 1, got {window}")
    if not 0 < p1 <= p2:
        raise ParameterError(f"penalties must satisfy 0 < P1 ≤ P2, got P1={p1}, P2={p2}")
    if paths not in (8, 16):
        raise ParameterError(f"paths must be 8 or 16, got {paths}")
    if mi_iterations < 1:
        raise ParameterError(f"mi_iterations must be at least 1, got {mi_iterations}")
    if not 0.0 <= uniqueness < 1.0:
        raise ParameterError(f"uniqueness must be in [0, 1), got {uniqueness}")
    if median > 1 and median % 2 == 0:
        raise ParameterError(f"median size must be odd, got {median}")
    workers = available_cores() if workers <= 0 else int(workers)
    timer = PhaseTimer()
    start = time.perf_counter()
    with timer.measure("prepare"):
        left_valid = np.isfinite(left)
        right_valid = np.isfinite(right)
        left_range = costs.robust_range([left], [left_valid])  # shared with the MI levels
        guide = costs.quantize(left, left_valid, 256, left_range)
        kappa = p2_kappa(guide, left_valid) if adaptive_p2 else 0
    common = dict(paths=paths, p1=p1, p2=p2, p2_kappa=kappa,
                  workers=workers, max_memory_mb=max_memory_mb,
                  unmatched_fraction=UNMATCHED_FRACTION, timer=timer)
    final = dict(subpixel=subpixel, lr_threshold=lr_threshold if lr_check else None)
    levels: list[dict[str, Any]] = []
    filters = dict(speckle_size=speckle_size, speckle_range=speckle_range, median=median,
                   timer=timer, uniqueness=uniqueness)
    match = dict(left=left, right=right, left_valid=left_valid, right_valid=right_valid,
                 guide=guide, left_range=left_range, min_disparity=min_disparity,
                 num_disparities=num_disparities, census_window=census_window,
                 mi_iterations=mi_iterations, seed=seed, common=common, final=final,
                 speckle=(speckle_size, speckle_range), levels=levels, workers=workers)
    fractions: dict[str, Any] = {}
    first = "hmi" if cost == "auto" else cost
    try:
        disparity, confidence = _match_cost(first, window=window, **match)
    except _NoMutualInformation as error:  # census can still match: fall back, say so
        log.warning("%s; matching with the census cost instead", error)
        fractions.update(cost_used="census", cost_reason=str(error))
        disparity, confidence = _census_fallback(cost_window, *given, match)
        first = "census"
    disparity, confidence, occluded = _filter(disparity, confidence, **filters)
    radius = _support_radius(first, window, census_window)
    if cost == "auto" and first == "hmi":
        (disparity, confidence, occluded), radius = _auto(
            (disparity, confidence, occluded), window=window, given=given,
            cost_window=cost_window,
            match=match, filters=filters, fractions=fractions)
    if fill and lr_check:  # foreground fattened across depth edges: back onto the edges
        with timer.measure("postprocess"):
            edge = kappa if adaptive_p2 else p2_kappa(guide, left_valid)
            snapped, moved = snap_edges(disparity, guide, radius,
                                        occluded & ~np.isfinite(disparity), min_step=edge)
            occluded = occluded | (moved & ~np.isfinite(snapped))
            disparity = snapped
            fractions["edge_moved"] = choice.share(moved, left_valid)
    disparity, confidence, classes = _fill(disparity, confidence, occluded,
                                           fill_mask=left_valid if fill else None,
                                           right_valid=right_valid, timer=timer)
    classes = classify(disparity, classes, min_disparity, num_disparities)
    fractions.update(class_fractions(classes, left_valid))
    timings = {k: round(v, 3) for k, v in timer.seconds.items()}
    timings["total"] = round(time.perf_counter() - start, 3)
    parameters = dict(cost=cost, census_window=census_window, cost_window=window,
                      paths=paths, p1=p1, p2=p2, adaptive_p2=adaptive_p2,
                      p2_kappa=kappa, mi_iterations=mi_iterations,
                      mi_levels=MI_LEVELS, mi_sigma=MI_SIGMA, subpixel=subpixel,
                      lr_check=lr_check, lr_threshold=lr_threshold,
                      speckle_size=speckle_size, speckle_range=speckle_range, median=median,
                      uniqueness=uniqueness, fill=fill,
                      min_disparity=min_disparity, num_disparities=num_disparities,
                      workers=workers, max_memory_mb=max_memory_mb, seed=seed)
    return SGMResult(disparity, confidence, parameters, timings, levels, classes, fractions)


class _NoMutualInformation(InputError):
    """The MI histogram has no valid pixel pairs (the census fallback takes over)."""


def _census_fallback(cost_window, p1, p2, match, defaults=None):
    """Census matching with its own defaults (``defaults``, else :data:`COST_DEFAULTS`)
    where the caller gave none."""
    defaults = COST_DEFAULTS["census"] if defaults is None else defaults
    common = dict(match["common"], p1=defaults.p1 if p1 is None else p1,
                  p2=defaults.p2 if p2 is None else p2)
    if common["p1"] > common["p2"]:
        common["p2"] = common["p1"]
    window = defaults.window if cost_window is None else int(cost_window)
    return _match_cost("census", window=window, **dict(match, common=common))


def _support_radius(cost: str, window: int, census_window: str) -> int:
    """Half-width (px, along a row) of the image patch one pixel's cost sees: how far a
    textured foreground can fatten into its neighbour (:mod:`demtool.sgm.edges`)."""
    radius = (window - 1) // 2
    if cost == "census":
        radius += CENSUS_WINDOWS[census_window][1] // 2
    return max(radius, 1)


def _auto(hmi, *, window, given, cost_window, match, filters, fractions, pixel_census=True):
    """The choices of cost "auto" after HMI (:mod:`demtool.sgm.auto`; ``pixel_census``
    False: the windowed choice alone).  ``hmi``: HMI's filtered (disparity, confidence,
    occluded), ``window`` its cost window.  Returns the chosen triple and its cost's
    support radius (:func:`demtool.sgm.edges.snap_edges`); the choice goes to ``fractions``."""
    valid, guide = match["left_valid"], match["guide"]
    census_window = match["census_window"]
    fractions["noise_sigma"] = round(noise := noise_sigma(guide, valid), 2)
    zone = (choice.discontinuity_zone(hmi[0])
            if pixel_census and noise <= choice.FINE_NOISE_MAX else None)
    if zone is not None and zone.any():  # no discontinuity (terrain): nothing to sharpen
        fine = _filter(*_census_fallback(cost_window, *given, match, choice.FINE_CENSUS),
                       **filters)
        if not (why_not := choice.prefer_fine(fine[0], hmi[0], valid)):
            log.info("cost auto: pixel census near depth discontinuities (noise σ %.1f)", noise)
            base, radius = _auto(hmi, window=window, given=given, cost_window=cost_window,
                                 match=match, filters=filters, fractions=fractions,
                                 pixel_census=False)
            fractions.update(cost_used=f"census+{fractions.get('cost_used', 'hmi')}",
                             edge_census=choice.share(zone, valid))
            window = choice.FINE_CENSUS.window if cost_window is None else int(cost_window)
            return (choice.blend_fine(fine, hmi, zone, base),
                    max(radius, _support_radius("census", window, census_window)))
        log.info("cost auto: no pixel census (%s)", why_not)
        fractions["cost_reason"] = why_not
    other = _filter(*_census_fallback(cost_window, *given, match), **filters)
    gradient = _filter(*_gradient_pass(cost_window, given, match), **filters)
    reason = choice.prefer_gradient(gradient[0], hmi[0], other[0], choice.full_range(
        valid, match["min_disparity"], match["num_disparities"]))
    if reason:
        log.info("cost auto: horizontal-gradient difference instead of HMI and census (%s)",
                 reason)
        fractions.update(cost_used="gradient", cost_reason=reason)
        gradient_window = COST_DEFAULTS["ad"].window if cost_window is None else cost_window
        return gradient, _support_radius("ad", int(gradient_window), census_window)
    return _windowed_choice(hmi, other, window=window, cost_window=cost_window,
                            match=match, fractions=fractions, filters=filters)


def _gradient_pass(cost_window, given, match):
    """Absolute difference of the images' horizontal Sobel gradients, with the "ad"
    defaults (OpenCV StereoSGBM's prefilter; an offset cancels, a gain scales)."""
    from scipy import ndimage  # only here: its import costs about a second

    images = {}
    for side in ("left", "right"):
        valid = match[f"{side}_valid"]
        filled = costs.fill_invalid(match[side], valid).astype(np.float64)
        images[side] = np.where(valid, ndimage.sobel(filled, axis=1),
                                np.nan).astype(np.float32)
    defaults = COST_DEFAULTS["ad"]
    p1, p2 = (d if g is None else g for g, d in zip(given, (defaults.p1, defaults.p2),
                                                     strict=True))
    guide = costs.quantize(images["left"], match["left_valid"], 256)
    common = dict(match["common"], p1=p1, p2=max(p1, p2))
    if common["p2_kappa"]:
        common["p2_kappa"] = p2_kappa(guide, match["left_valid"])
    window = defaults.window if cost_window is None else int(cost_window)
    return _match_cost("ad", window=window, **dict(match, common=common, guide=guide,
                                                    **images))


def _windowed_choice(hmi, other, *, window, cost_window, match, fractions, filters):
    """HMI, census summed over a window, or the HMI pixels census confirms (near depth
    edges the pixel census, :func:`_edge_census`)."""
    valid, census_window = match["left_valid"], match["census_window"]
    hmi_radius = _support_radius("hmi", window, census_window)
    reason = choice.prefer_census(hmi[0], other[0], valid, match["min_disparity"],
                                  match["num_disparities"])
    fractions["cost_used"] = "census" if reason else "hmi"
    if reason:
        log.info("cost auto: census instead of HMI (%s)", reason)
        fractions["cost_reason"] = reason
        window = COST_DEFAULTS["census"].window if cost_window is None else int(cost_window)
        return other, _support_radius("census", window, census_window)
    agreed, share = choice.agreement(hmi[0], other[0])
    if share < choice.AUTO_AGREEMENT:
        log.info("cost auto: HMI kept (census agrees on only %.1f %% of its matches)",
                 100 * share)
        return hmi, hmi_radius
    log.info("cost auto: HMI and census agree on %.1f %% of HMI's matches; keeping those, "
             "the rest is filled", 100 * share)
    fractions["cost_used"] = "hmi+census"
    disparity, confidence = (np.where(agreed, a, np.float32(np.nan)).astype(np.float32)
                             for a in (hmi[0], np.minimum(hmi[1], other[1])))
    result, zone = (disparity, confidence, hmi[2] | other[2]), choice.depth_edge_zone(disparity)
    if zone.any():  # where the windowed costs fatten a foreground
        fractions["edge_census"] = choice.share(zone, valid)
        log.info("cost auto: pixel census near depth edges (%.1f %% of the pixels)",
                 100 * fractions["edge_census"])
        result = choice.at_depth_edges(zone, result, _edge_census(match, filters))
    return result, hmi_radius


def _edge_census(match, filters):
    """:data:`choice.EDGE_CENSUS` from the left and the right image, cross-checked
    (:func:`choice.cross_check`; not with ``lr_check`` off).  P2 constant: no guide."""
    census = choice.EDGE_CENSUS
    options = dict(window=census.window, common=dict(match["common"], p1=census.p1,
                   p2=census.p2, p2_kappa=0), final=dict(match["final"], lr_threshold=None))
    left = _filter(*_match_cost("census", **dict(match, **options)), **filters)
    if match["final"]["lr_threshold"] is None:
        return left
    right = _filter(*_match_cost("census", **dict(match, **options, **choice.mirrored(match))),
                    **filters)
    return choice.cross_check(left[0], left[1], right[0][:, ::-1],
                              match["final"]["lr_threshold"])


def _match_cost(cost, *, left, right, left_valid, right_valid, guide, left_range,
                min_disparity, num_disparities, window, census_window, mi_iterations, seed,
                common, final, speckle, levels, workers):
    """The raw disparity and confidence of one cost (before filters and fill)."""
    timer: PhaseTimer = common["timer"]
    if cost in ("census", "ad"):
        with timer.measure("prepare"):
            if cost == "census":
                pixel_cost = costs.census_pixel_cost(costs.fill_invalid(left, left_valid),
                                                     costs.fill_invalid(right, right_valid),
                                                     CENSUS_WINDOWS[census_window],
                                                     workers=workers)
            else:
                value_range = costs.robust_range([left, right], [left_valid, right_valid])
                pixel_cost = costs.table_pixel_cost(
                    "ad", costs.quantize(left, left_valid, 256, value_range),
                    costs.quantize(right, right_valid, 256, value_range),
                    costs.absolute_difference_table(256, AD_TRUNCATION))
        disparity, confidence = match_pass(
            pixel_cost, left_valid, right_valid, guide, min_disparity=min_disparity,
            num_disparities=num_disparities, window=window, **common, **final)
        levels.append({"scale": 1, "cost": cost, "min_disparity": min_disparity,
                       "num_disparities": num_disparities,
                       "valid_fraction": float(np.isfinite(disparity).mean())})
        return disparity, confidence
    return _mutual_information_sgm(
        left, right, left_valid, right_valid, guide, cost=cost,
        min_disparity=min_disparity, num_disparities=num_disparities, window=window,
        mi_iterations=mi_iterations, seed=seed, common=common, final=final,
        speckle=speckle, levels=levels, left_range=left_range)


def _mutual_information_sgm(left, right, left_valid, right_valid, guide, *, cost, min_disparity,
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
    for index, (scale, image_l, image_r, valid_l, valid_r, level_guide) in enumerate(pyramid):
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
                    raise _NoMutualInformation(
                        "no valid corresponding pixels for the MI histogram at 1/"
                        f"{scale} scale (disparities {lo} … {hi})")
                pixel_cost = costs.table_pixel_cost("mi", levels_l, levels_r,
                                                    costs.mi_cost_table(mi))
            final_pass = last_level and iteration == iterations - 1
            options = final if final_pass else dict(subpixel="none", lr_threshold=1.0)
            disparity, confidence = match_pass(
                pixel_cost, valid_l, valid_r, level_guide, min_disparity=lo,
                num_disparities=count, window=window, **common, **options)
            if not final_pass:
                disparity, _ = _postprocess(disparity, confidence, speckle_size=speckle[0],
                                            speckle_range=speckle[1], median=3, timer=timer)
            levels.append({"scale": scale, "iteration": iteration + 1, "min_disparity": lo,
                           "num_disparities": count, "mi_levels": n_levels, "mi_pairs": pairs,
                           "valid_fraction": float(np.isfinite(disparity).mean())})
            log.debug("MI level 1/%d iteration %d: %d disparities, %.1f %% valid", scale,
                      iteration + 1, count, 100 * levels[-1]["valid_fraction"])
            estimate = disparity
        previous = estimate
    return disparity, confidence
