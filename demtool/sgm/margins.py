"""How far an SGM result reaches: the margin of a tile, from P2 and the cost's contrast.

A tile is matched on its core plus a margin and cropped to the core; the margin must
hold everything that changes a core pixel's disparity: the matching cost's support
(the census window and the cost window), the post-filters (median, speckles, the
edge snapping) and, the longest, the memory of SGM's paths.

**Path memory** (Hirschmüller 2008, eq. 13).  Write the path cost relative to its
minimum, ℓ(p, d) = L_r(p, d) − min_k L_r(p, k) ≥ 0.  Eq. 13 is then

    L_r(p, d) = C(p, d) + min(ℓ(p − r, d), ℓ(p − r, d ± 1) + P1, P2),

so whatever happened before p − r enters only through ``min(ℓ, P2)``: a disparity
whose ℓ has reached P2 has *forgotten* where the path started.  Along a path, the ℓ of
a wrong disparity grows by its cost excess over the best one, on average ΔC̄ per step
(the cost's *contrast*), so after about P2 / ΔC̄ steps every wrong disparity is at the
cap and the path's state no longer depends on its start: a tile's paths, which start at
its edge, then give the untiled paths' sums (the disparities near the best one, tied to
it by P1 chains, converge with it).  Where the texture is weak, ΔC̄ is small and the
memory long; the image decides.  The reach used is

    reach = ⌈κ · P2 / ΔC̄⌉,  κ = :data:`REACH_FACTOR`,

with ΔC̄ the :data:`CONTRAST_PERCENTILE`-th percentile over the pixels of a sample of
the pair of ``mean_d C(p, d) − min_d C(p, d)`` (the window-summed cost, all disparities
of the range; :func:`cost_contrast`).  κ = 4 was calibrated on two synthetic pairs of
``bench/_scale_pairs.py`` (census 5×5, window 5, P2 1200, 96 disparities; cores of 256
px inside a 1024² pair matched whole; disparities before the filters and fill):

| texture | ΔC̄ (p10) | identical at margin 16 / 32 / 48 / 64 px | reach + support |
|---|---|---|---|
| contrast 6 (bench/scale_out.py's) | 127 | 99.91 / 99.999 / 100 / 100 % | 38 + 4 |
| contrast 1.5 (at the noise) | 70 | 95.0 / 98.7 / 99.5 / 99.8 % | 69 + 4 |

(contrast 1.5 within 0.1 px: 98.9 / 99.6 / 99.8 / 99.95 %.)

Without a measurement (no sampled pixel with data at every disparity) ΔC̄ is modelled
as a texture at its noise level, :data:`WEAK_CONTRAST` of the window-summed cost's range.
For the MI costs ("hmi", "mi" and "auto", which starts from HMI) a tile computes its own
mutual-information table from its own pixels, so tiles differ from the untiled run
whatever the margin; their margin is not re-derived: the fixed 64 px path margin plus
the windows, as before (:func:`mi_margin`).

References
----------
Hirschmüller, H. (2008), Stereo processing by semiglobal matching and mutual
information, IEEE TPAMI 30(2), 328–341 (eq. 13; §3.1.3 on P1, P2).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

REACH_FACTOR = 4.0  # κ: path steps, in units of P2 / ΔC̄ (module docstring)
CONTRAST_PERCENTILE = 10.0  # ΔC̄: this percentile of the per-pixel contrast
# ΔC̄ of a texture at its noise level, as a fraction of the window-summed cost's range
# (census 5×5, window 5: 70 of 600 on the contrast-1.5 pair of the docstring's table)
WEAK_CONTRAST = 0.115
MI_FLOOR = 64  # px: the MI costs' fixed path margin (:func:`mi_margin`)
SAMPLE_ROWS = 64  # rows of each sample window of the pair (:func:`sample_windows`)
SAMPLES = 4  # windows, spread over the image


def path_reach(p2: float, contrast: float) -> int:
    """Steps after which a path has forgotten its start: ⌈κ · P2 / ΔC̄⌉ (px).

    Parameters
    ----------
    p2 : float
        The penalty of a disparity jump, cost units (the adaptive P2 only lowers it).
    contrast : float
        ΔC̄, the cost's typical excess of a wrong disparity over the best, per pixel
        step, cost units (:func:`cost_contrast`); ≤ 0: no texture, no finite reach.
    """
    if not contrast > 0:
        raise ValueError(f"the cost's contrast must be positive, got {contrast}")
    return int(math.ceil(REACH_FACTOR * float(p2) / float(contrast)))


def cost_contrast(windows, *, cost: str, window: int, census_shape: tuple[int, int],
                  min_disparity: int, num_disparities: int) -> float | None:
    """ΔC̄ of samples of the pair: the :data:`CONTRAST_PERCENTILE`-th percentile over
    their pixels of ``mean_d C(p, d) − min_d C(p, d)``, C the window-summed pixel cost.

    Parameters
    ----------
    windows : iterable of (left, right), each (h, w) float32, NaN = invalid
        Windows of the rectified pair (the same rows and columns of both images).
    cost : {"census", "ad"}
    window : int, the cost window's side
    census_shape : (rows, columns) of the census window
    min_disparity, num_disparities : int, the range searched

    Returns
    -------
    float, cost units per pixel, or None when no sampled pixel has valid data at every
    disparity (then the caller falls back on the model).
    """
    excess = [contrast_samples(left, right, cost=cost, window=window,
                               census_shape=census_shape, min_disparity=min_disparity,
                               num_disparities=num_disparities) for left, right in windows]
    values = np.concatenate(excess) if excess else np.empty(0)
    return float(np.percentile(values, CONTRAST_PERCENTILE)) if values.size else None


def contrast_samples(left: np.ndarray, right: np.ndarray, *, cost: str, window: int,
                     census_shape: tuple[int, int], min_disparity: int,
                     num_disparities: int) -> np.ndarray:
    """``mean_d C − min_d C`` (float64, cost units) at the pixels of one window of the
    pair whose cost window is inside it and valid and whose every match is inside it
    (see :func:`cost_contrast`).

    Plain numpy on a small window (the costs of :mod:`demtool.sgm.cost`: census codes
    of "darker than the centre" bits, Zabih & Woodfill 1994, compared by Hamming
    distance; the absolute difference of 256 grey levels of the pair's joint 0.5 …
    99.5 % stretch truncated at :data:`demtool.sgm.passes.AD_TRUNCATION`), so that the
    process planning the tiles loads none of the compiled kernels.
    """
    from demtool.sgm.cost import fill_invalid
    from demtool.sgm.passes import AD_TRUNCATION

    left_valid, right_valid = np.isfinite(left), np.isfinite(right)
    height, width = left.shape
    radius = window // 2
    max_disparity = min_disparity + num_disparities - 1
    x0, x1 = radius + max(max_disparity, 0), width - radius + min(min_disparity, 0)
    if not (left_valid.any() and right_valid.any()) or x1 <= x0 or height <= 2 * radius:
        return np.empty(0)
    fill_l = fill_invalid(left, left_valid)
    fill_r = fill_invalid(right, right_valid)
    if cost == "census":
        codes = [_census_codes(image, census_shape) for image in (fill_l, fill_r)]
    elif cost == "ad":
        both = np.concatenate([fill_l[left_valid], fill_r[right_valid]])
        low, high = np.percentile(both, (0.5, 99.5))
        scale = 255.0 / (high - low) if high > low else 1.0
        codes = [np.clip(np.rint((image - low) * scale), 0, 255).astype(np.int16)
                 for image in (fill_l, fill_r)]
    else:
        raise ValueError(f"the contrast is measured for census and ad, not {cost!r}")
    # C(y, x, k) at the columns x0 − radius … x1 + radius whose windows are then summed
    first, last = x0 - radius, x1 + radius
    pixel = np.empty((num_disparities, height, last - first), dtype=np.int32)
    here = codes[0][:, first:last]
    for k in range(num_disparities):
        d = min_disparity + k
        matched = codes[1][:, first - d:last - d]
        if cost == "census":
            pixel[k] = np.bitwise_count(here ^ matched)
        else:
            pixel[k] = np.minimum(np.abs(here - matched), AD_TRUNCATION)
    summed = _box_sum(pixel, window)  # (D, height − 2r, x1 − x0)
    # pixels whose whole cost window is valid (the kernels cost a NaN pixel as unmatched)
    holes = _box_sum((~left_valid[None, :, first:last]).astype(np.int32), window)[0]
    inside = holes == 0
    values = summed[:, inside]
    return values.mean(axis=0) - values.min(axis=0)


def _census_codes(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) uint64 census codes of ``image`` (edges replicated), one bit per
    neighbour of the ``shape`` (rows, columns) window, set where it is darker."""
    rows, cols = shape
    padded = np.pad(image, ((rows // 2,), (cols // 2,)), mode="edge")
    height, width = image.shape
    centre = padded[rows // 2:rows // 2 + height, cols // 2:cols // 2 + width]
    codes = np.zeros(image.shape, dtype=np.uint64)
    for dy in range(rows):
        for dx in range(cols):
            if dy == rows // 2 and dx == cols // 2:
                continue
            darker = padded[dy:dy + height, dx:dx + width] < centre
            codes = (codes << np.uint64(1)) | darker.astype(np.uint64)
    return codes


def _box_sum(volume: np.ndarray, window: int) -> np.ndarray:
    """Sums of ``volume`` (D, H, W) int32 over ``window × window`` squares of its last
    two axes: (D, H − w + 1, W − w + 1)."""
    if window <= 1:
        return volume
    w = window
    rows = np.cumsum(volume, axis=1, dtype=np.int32)
    rows = np.concatenate([rows[:, w - 1:w], rows[:, w:] - rows[:, :-w]], axis=1)
    both = np.cumsum(rows, axis=2, dtype=np.int32)
    return np.concatenate([both[:, :, w - 1:w], both[:, :, w:] - both[:, :, :-w]], axis=2)


def sample_windows(height: int, width: int, num_disparities: int, window: int
                   ) -> list[tuple[int, int, int, int]]:
    """Up to :data:`SAMPLES` windows (row0, row1, col0, col1) spread over the image,
    each :data:`SAMPLE_ROWS` rows and as wide as the disparity range plus 256 columns
    (the whole image when it is smaller)."""
    rows = min(height, SAMPLE_ROWS + window)
    cols = min(width, 256 + num_disparities + window)
    out: list[tuple[int, int, int, int]] = []
    for fy, fx in ((0.25, 0.25), (0.25, 0.75), (0.75, 0.25), (0.75, 0.75))[:SAMPLES]:
        r0 = min(max(0, int(fy * height) - rows // 2), height - rows)
        c0 = min(max(0, int(fx * width) - cols // 2), width - cols)
        box = (r0, r0 + rows, c0, c0 + cols)
        if box not in out:
            out.append(box)
    return out


def modelled_contrast(cost: str, window: int, census_shape: tuple[int, int]) -> float:
    """ΔC̄ of a texture at its noise level: :data:`WEAK_CONTRAST` of the window-summed
    cost's range (census: the code's bits; MI 0 … 64; absolute difference 0 … 24)."""
    from demtool.sgm.passes import AD_TRUNCATION

    pixel_range = {"census": census_shape[0] * census_shape[1] - 1, "mi": 64,
                   "ad": AD_TRUNCATION}[cost]
    return WEAK_CONTRAST * pixel_range * window * window


def mi_margin(params: Any) -> int:
    """The margin of an MI-cost tile ("hmi", "mi", "auto"), px: :data:`MI_FLOOR` + the
    cost, census and median windows + the speckle reach (not re-derived: a tile's MI
    table is its own, so its result differs from the untiled one whatever the margin)."""
    from demtool.sgm.matcher import CENSUS_WINDOWS, COST_DEFAULTS

    names = {"hmi": ("mi",), "auto": ("mi", "census")}.get(params.cost, (params.cost,))
    window = params.cost_window or max(COST_DEFAULTS[name].window for name in names)
    census = max(CENSUS_WINDOWS[params.census_window])
    speckle = int(math.ceil(math.sqrt(max(params.speckle_size, 0))))
    return MI_FLOOR + window + census + params.median + speckle


def tile_margin(params: Any, contrast: dict[str, float] | None = None) -> tuple[int, dict]:
    """The margin of an sgm tile, px, and how it was made (for the sidecar).

    Census and "ad": the path reach (:func:`path_reach`, with the measured
    ``contrast[cost]`` when given, else :func:`modelled_contrast`) plus the cost's
    support (half the cost window and, for census, half the census window's width);
    then half the median window, the speckle filter's reach (√ of its region size) and
    the edge snapping's reach (the cost's support,
    :func:`demtool.sgm.passes.support_radius`).  The MI costs: :func:`mi_margin`.
    """
    from demtool.sgm.matcher import CENSUS_WINDOWS, COST_DEFAULTS

    if params.cost in ("hmi", "mi", "auto"):
        margin = mi_margin(params)
        return margin, {"margin_px": margin, "passes": [],
                        "rule": "fixed: 64 px + windows (MI costs: per-tile MI tables)"}
    census_shape = CENSUS_WINDOWS[params.census_window]
    defaults = COST_DEFAULTS[params.cost]
    window = int(params.cost_window or defaults.window)
    p2 = int(params.p2 or defaults.p2)
    measured = (contrast or {}).get(params.cost)
    delta = measured if measured else modelled_contrast(params.cost, window, census_shape)
    steps = path_reach(p2, delta)
    support = window // 2 + (census_shape[1] // 2 if params.cost == "census" else 0)
    speckle = int(math.ceil(math.sqrt(max(params.speckle_size, 0))))
    margin = steps + support + params.median // 2 + speckle + support
    return margin, {"margin_px": margin, "cost": params.cost, "window": window, "p2": p2,
                    "contrast": round(float(delta), 1),
                    "contrast_source": "measured" if measured else "model",
                    "path_reach_px": steps, "support_px": support,
                    "median_px": params.median // 2, "speckle_px": speckle,
                    "edge_snap_px": support}
