"""A disparity search range estimated from matches, widened where SGM saturates at its bounds.

``rectify`` and the ortho-pair route (:mod:`demtool.mapproject.stereo`) estimate the search range
from the sparse SIFT matches of the pair (their 1st–99th percentiles plus a margin).  Where
the terrain the matches miss lies beyond that range — a deep crater with a shadowed,
featureless floor, a peak without texture — winner-takes-all can only answer the range's
bound: those pixels come out *exactly* at the bound (sub-pixel interpolation needs a cost on
both sides), and once triangulated they are metres off (the synthetic line-scan scene of
seed 4: a 44 m crater 23 m too shallow, RMSE 1.65 m against 0.22 m elsewhere).  A pixel at
the bound is the matcher's own evidence that the range is too narrow, so
:func:`sgm_widening` matches again with that side extended by half the range (at least
:data:`MIN_STEP_PX`), up to ``widenings`` times — the answer ASP users give by hand with a
wider ``corr-search``, needing no prior knowledge of the relief.

On a calibrated pair (``rectify --sensor-left/--sensor-right``) the rectified cameras share
one orientation, so a point at infinity has the disparity ``d∞ = cx_left − cx_right``
(rectify.npz ``disparity_infinity``) and every point in front of both cameras a larger one
(``d = d∞ + f B / Z``).  Pixels at a lower bound that already reaches ``d∞`` are sky or
horizon, not terrain beyond the range: the lower side is never widened past
``lower_limit`` (``⌊d∞⌋ − 1``), and a side stuck at its limit is not "saturated".  When
the models also bound the scene's depth (``Z ≥ Z_min``), ``upper_limit`` caps the other
side at ``d∞ + f B / Z_min``.  Ranges are written ``min … max`` (both searched) in the
logs and ``[min, max]`` in the history.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from demtool.logs import get_logger

log = get_logger(__name__)

#: pixels exactly at a bound that make it saturated: at least this many …
MIN_SATURATED_PX = 32
#: … and at least this fraction of the valid disparities (isolated mismatches stay)
MIN_SATURATED_FRACTION = 1e-4
#: smallest widening of a saturated side, pixels
MIN_STEP_PX = 4


def limits_from_rectification(rectification) -> tuple[int | None, int | None]:
    """(lower_limit, upper_limit) of the widening from a rectify.npz's arrays.

    ``disparity_infinity`` (calibrated pairs: the disparity of a point at infinity) gives
    ``⌊d∞⌋ − 1``; ``disparity_nearest`` (the disparity of the scene's nearest depth,
    when the models bound it) gives ``⌈d_near⌉ + 1``; None where the file has no such key
    (uncalibrated pairs: nothing bounds the range but the image).
    """
    import math

    def value(key):
        if key not in rectification:
            return None
        v = float(np.asarray(rectification[key]))
        return v if math.isfinite(v) else None

    infinity, nearest = value("disparity_infinity"), value("disparity_nearest")
    return (None if infinity is None else math.floor(infinity) - 1,
            None if nearest is None else math.ceil(nearest) + 1)


def saturated_bounds(disparity: np.ndarray, min_disparity: int, num_disparities: int
                     ) -> tuple[int, int]:
    """Numbers of pixels exactly at the lower and the upper bound of the search range.

    Parameters
    ----------
    disparity : (H, W) float array
        SGM disparity, pixels, NaN = invalid.
    min_disparity, num_disparities : int
        The range it was searched over: ``min_disparity … min_disparity +
        num_disparities − 1``.

    Returns
    -------
    (int, int)
        Pixels equal to the lower bound, pixels equal to the upper bound.
    """
    values = disparity[np.isfinite(disparity)]
    high = min_disparity + num_disparities - 1
    return int(np.count_nonzero(values == min_disparity)), int(np.count_nonzero(values == high))


def is_saturated(count: int, valid: int) -> bool:
    """Whether ``count`` pixels at a bound, of ``valid`` valid ones, saturate it."""
    return count >= max(MIN_SATURATED_PX, MIN_SATURATED_FRACTION * valid)


def widened_range(min_disparity: int, num_disparities: int, low: bool, high: bool,
                  width: int, *, lower_limit: int | None = None,
                  upper_limit: int | None = None) -> tuple[int, int]:
    """The range with each saturated side extended by half its span (≥ MIN_STEP_PX),
    kept inside what an image ``width`` pixels wide allows (|d| < width, span < width)
    and inside ``lower_limit … upper_limit`` when given (the disparity at infinity and
    at the scene's nearest depth of a calibrated pair); never narrower than given."""
    step = max(MIN_STEP_PX, num_disparities // 2)
    old_upper = min_disparity + num_disparities - 1
    lower = max(min_disparity - step if low else min_disparity, -(width - 1))
    upper = min(old_upper + step if high else old_upper, width - 1)
    if lower_limit is not None:
        lower = min(max(lower, int(lower_limit)), min_disparity)
    if upper_limit is not None:
        upper = max(min(upper, int(upper_limit)), old_upper)
    excess = upper - lower + 2 - width  # the span must stay below the width
    if excess > 0:  # give back the widening, upper side first
        cut = min(excess, upper - old_upper)
        upper -= cut
        lower += min(excess - cut, min_disparity - lower)
    return lower, upper - lower + 1


def sgm_widening(left: np.ndarray, right: np.ndarray, *, min_disparity: int,
                 num_disparities: int, widenings: int = 2, lower_limit: int | None = None,
                 upper_limit: int | None = None, **options: Any):
    """:func:`demtool.sgm.sgm`, matched again over a wider range while it saturates.

    Parameters
    ----------
    left, right : (H, W) float arrays
        The rectified pair (see :func:`demtool.sgm.sgm`).
    min_disparity, num_disparities : int
        The estimated search range, pixels.
    widenings : int
        Largest number of re-matches (0: match once over the given range).
    lower_limit, upper_limit : int, optional
        Disparities no widening goes beyond (pixels): a calibrated pair's disparity at
        infinity (minus one pixel) and at the scene's nearest depth.  A side already at
        its limit is not widened.
    **options
        The other keywords of :func:`demtool.sgm.sgm`.

    Returns
    -------
    SGMResult
        The last match; ``parameters["min_disparity"]``/``["num_disparities"]`` are the
        range it searched and ``parameters["range_widenings"]`` lists each widening as
        ``{"from": [min, max], "to": [min, max], "saturated_low": n, "saturated_high": n}``
        (both ends searched, pixels; the convention of the logs);
        ``timings["total"]`` sums every match, the other timings are the last one's.
    """
    from demtool.sgm.matcher import sgm

    width = np.asarray(left).shape[1]
    history: list[dict[str, Any]] = []
    seconds = 0.0
    while True:
        result = sgm(left, right, min_disparity=min_disparity,
                     num_disparities=num_disparities, **options)
        seconds += result.timings.get("total", 0.0)
        valid = int(np.isfinite(result.disparity).sum())
        at_low, at_high = saturated_bounds(result.disparity, min_disparity, num_disparities)
        low, high = is_saturated(at_low, valid), is_saturated(at_high, valid)
        upper = min_disparity + num_disparities - 1
        low &= lower_limit is None or min_disparity > lower_limit
        high &= upper_limit is None or upper < upper_limit
        if not (low or high) or len(history) >= widenings:
            if low or high:
                log.warning("%d / %d pixels at the disparity range's lower / upper bound "
                            "%d … %d%s: the terrain there may lie beyond the range (give a "
                            "wider one with --min-disparity/--num-disparities)", at_low,
                            at_high, min_disparity, min_disparity + num_disparities - 1,
                            f" after {len(history)} widening(s)" if history else "")
            break
        wider = widened_range(min_disparity, num_disparities, low, high, width,
                              lower_limit=lower_limit, upper_limit=upper_limit)
        if wider == (min_disparity, num_disparities):
            break
        log.warning("%d / %d pixels at the disparity range's lower / upper bound %d … %d "
                    "(terrain beyond the matches' range): matching again over %d … %d",
                    at_low, at_high, min_disparity, min_disparity + num_disparities - 1,
                    wider[0], wider[0] + wider[1] - 1)
        history.append({"from": [min_disparity, upper],
                        "to": [wider[0], wider[0] + wider[1] - 1],
                        "saturated_low": at_low, "saturated_high": at_high})
        min_disparity, num_disparities = wider
    result.parameters["range_widenings"] = history
    result.timings["total"] = round(seconds, 3)
    return result
