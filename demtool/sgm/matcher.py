"""Semi-global matching of a rectified pair: checks, the cost's passes, edges and fill.

:func:`sgm` is the stage's core (arrays in, arrays out); one cost's pass (and the MI /
HMI schedule) is :mod:`demtool.sgm.passes`, the default cost's choices
:mod:`demtool.sgm.auto`.  Each SGM pass holds one
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

import functools
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from demtool.errors import InputError, ParameterError
from demtool.logs import get_logger
from demtool.sgm import auto as choice
from demtool.sgm import cost as costs
from demtool.sgm.edges import snap_edges
from demtool.sgm.fill import class_fractions, classify
from demtool.sgm.noise import (  # noqa: F401  (re-exported: part of this module's API)
    P2_KAPPA,
    P2_KAPPA_NOISE,
    noise_sigma,
    p2_kappa,
)
from demtool.sgm.passes import (  # noqa: F401  (COST_DEFAULTS: part of this module's API)
    COST_DEFAULTS,
    MI_SIGMA,
    UNMATCHED_FRACTION,
    CostDefaults,
    NoMutualInformation,
    census_fallback,
    fill_pass,
    filter_pass,
    match_cost,
    support_radius,
)
from demtool.sgm.pyramid import MI_LEVELS, mi_levels  # noqa: F401  (mi_levels: this API)
from demtool.sgm.strips import (  # noqa: F401  (plan_strips: part of this module's API)
    PhaseTimer,
    plan_strips,
)
from demtool.tiling.distributed import available_cores, threads_limited

log = get_logger(__name__)

COSTS = ("auto", "hmi", "mi", "census", "ad")
CENSUS_WINDOWS = {"5x5": (5, 5), "9x7": (7, 9)}  # (rows, columns): 9 wide, 7 high


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


def _threads_of_workers(function):
    """Run the matcher with ``workers`` resolved (≤ 0: the cores) and
    :func:`demtool.tiling.distributed.threads_limited` set to it, so its post-processing
    threads follow ``--workers``."""
    @functools.wraps(function)
    def limited(*args, workers: int = 0, **kwargs):
        workers = available_cores() if workers <= 0 else int(workers)
        with threads_limited(workers):
            return function(*args, workers=workers, **kwargs)

    return limited


@_threads_of_workers
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
        Budget of S and the row buffers of the strips matched at once, and of the
        results cost "auto" holds from its earlier passes, MiB (beyond it the sweeps
        recompute their end rows: same result, ~13 % more CPU; issue 28).
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
                 num_disparities=num_disparities, census_shape=CENSUS_WINDOWS[census_window],
                 mi_iterations=mi_iterations, seed=seed, common=common, final=final,
                 speckle=(speckle_size, speckle_range), levels=levels, workers=workers)
    fractions: dict[str, Any] = {}
    first = "hmi" if cost == "auto" else cost
    try:
        disparity, confidence = match_cost(first, window=window, **match)
    except NoMutualInformation as error:  # census can still match: fall back, say so
        log.warning("%s; matching with the census cost instead", error)
        fractions.update(cost_used="census", cost_reason=str(error))
        disparity, confidence = census_fallback(cost_window, *given, match)
        first = "census"
    disparity, confidence, occluded = filter_pass(disparity, confidence, **filters)
    radius = support_radius(first, window, CENSUS_WINDOWS[census_window])
    if cost == "auto" and first == "hmi":
        (disparity, confidence, occluded), radius = choice.choose(
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
    disparity, confidence, classes = fill_pass(disparity, confidence, occluded,
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
