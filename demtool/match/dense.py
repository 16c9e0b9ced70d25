"""Dense area-based matching of a rectified pair: the HiRISE Dense Matcher scheme.

1. Seeds (:mod:`demtool.match.seeds`) are triangulated; every pixel gets an initial
   disparity (barycentric interpolation) and a search range (its triangle's vertex
   disparities ± a margin) — :mod:`demtool.match.triangles`.
2. Coarse to fine through a Gaussian pyramid, NCC (:mod:`demtool.match.ncc`) finds
   the best disparity of every pixel inside its range; each level's result, cleaned
   by a 3 × 3 median test, narrows the next finer level's range to ±2 pixels around
   it (still inside the triangle range).
3. At full resolution least-squares matching (:mod:`demtool.match.lsm`) refines
   each template centre on the grid to sub-pixel precision with its standard
   deviation; a match is accepted when LSM converges with a correlation coefficient
   of at least the acceptance threshold, stays on its row and inside its range.
4. Densification: accepted matches (one per ``template``-sized cell, the best
   correlated) join the seeds, the triangulation is rebuilt and the rejected grid
   nodes are matched again inside the tighter triangles, for a few rounds.

With a grid spacing ``s > 1`` (default 2) only every ``s``-th row and column is
matched; a pixel between four accepted nodes that agree within
``INTERPOLATION_TOLERANCE`` gets their bilinear interpolation, a pixel with some but not
such corners (a disparity edge, the border of the accepted area) is matched itself, and
a pixel with no accepted corner stays NaN.

5. Refinement (``refine``, default 1 iteration): every accepted disparity, matched or
   interpolated, is refined with its own template by a translation-only
   inverse-compositional Gauss–Newton step whose template shape is the LSM affine
   solution (bilinear between the nodes) — :mod:`demtool.match.between`.  It restores
   the detail that interpolation between nodes smooths, at about a fifth of the cost of
   matching every pixel.

References
----------
Grün, A. (1985). Adaptive least squares correlation. S. Afr. J. Photogramm. 14(3).
Wu, B., Zhang, Y., Zhu, Q. (2012). Integrated point and edge matching on poor
    textural images constrained by self-adaptive triangulations. ISPRS J. 68, 40-55.
Kirk, R. L., et al. (2008). Ultrahigh resolution topographic mapping of Mars with
    MRO HiRISE stereo images. JGR 113, E00A24 (the SOCET SET/NGATE workflow).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from demtool.errors import ParameterError, ProcessingError
from demtool.logs import get_logger
from demtool.match.between import between_nodes, polish, spread_nodes
from demtool.match.lsm import lsm_match
from demtool.match.lsm_base import CONVERGED
from demtool.match.ncc import build_pyramid, integral_invalid, ncc_search
from demtool.match.seeds import Seeds, check_seed_points, find_seeds
from demtool.match.triangles import SeedTriangulation

log = get_logger(__name__)

#: NCC correlation a coarse pyramid level's match needs to guide the next level.
COARSE_MIN_CORRELATION = 0.5
#: Half-width (pixels of the finer level) of the range around the coarser result.
PYRAMID_RADIUS = 2
#: LSM is tried only where the NCC peak reaches the acceptance threshold minus this,
#: and gives up after two iterations still this far below the threshold.
LSM_NCC_SLACK = 0.3
#: Largest spread (pixels) of four accepted node disparities interpolated in between
#: with a grid spacing > 1; pixels at wider spreads (disparity edges) are matched.
INTERPOLATION_TOLERANCE = 1.0


@dataclass(frozen=True)
class MatchResult:
    """Result of :func:`match`.

    Attributes
    ----------
    disparity : (H, W) float32
        Disparity in the left (rectified) frame, pixels, ``x_right = x_left − d``;
        NaN where no match was accepted.
    correlation : (H, W) float32
        LSM correlation coefficient of every evaluated template (accepted or not;
        NaN where LSM did not converge or nothing was evaluated).
    sigma : (H, W) float32
        LSM standard deviation of the accepted disparities, pixels; NaN elsewhere.
    seeds : Seeds
        The verified seed matches used (after blunder removal).
    summary : dict
        Completeness, counts per stage and round, timings.
    """

    disparity: np.ndarray
    correlation: np.ndarray
    sigma: np.ndarray
    seeds: Seeds
    summary: dict = field(default_factory=dict)

    @property
    def completeness(self) -> float:
        """Percentage of the left image's valid pixels with an accepted disparity."""
        return float(self.summary.get("completeness_percent", 0.0))


def check_parameters(template: int, threshold: float, grid_spacing: int, levels: int,
                     search_margin: float, rounds: int, weighting: float = 0.0,
                     refine: int = 0) -> None:
    """Raise ParameterError for option values outside their ranges."""
    if refine < 0:
        raise ParameterError(f"refine must be >= 0 iterations (0 = off), got {refine}")
    if not (np.isfinite(weighting) and weighting >= 0):
        raise ParameterError(f"weighting must be a Gaussian sigma >= 0 pixels (0 = uniform), "
                             f"got {weighting}")
    if not (9 <= template <= 25 and template % 2 == 1):
        raise ParameterError(f"template must be an odd size from 9 to 25 pixels, got {template}")
    if not 0.0 < threshold < 1.0:
        raise ParameterError(f"threshold must be a correlation in (0, 1), got {threshold}")
    if grid_spacing < 1:
        raise ParameterError(f"grid spacing must be >= 1 pixel, got {grid_spacing}")
    if not 1 <= levels <= 8:
        raise ParameterError(f"levels must be 1 to 8, got {levels}")
    if not (np.isfinite(search_margin) and search_margin >= 0):
        raise ParameterError(f"search margin must be >= 0 pixels, got {search_margin}")
    if rounds < 0:
        raise ParameterError(f"densification rounds must be >= 0, got {rounds}")


def _nan_median3(grid: np.ndarray) -> np.ndarray:
    """3 × 3 median of the finite neighbours (NaN where none)."""
    padded = np.pad(grid, 1, constant_values=np.nan)
    height, width = grid.shape
    stack = np.stack([padded[dy:dy + height, dx:dx + width]
                      for dy in range(3) for dx in range(3)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN neighbourhoods
        return np.nanmedian(stack, axis=0)


def _sample_coarse(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear sample of a NaN-holed coarse grid at fractional (row, col); NaN if empty."""
    from scipy import ndimage

    valid = np.isfinite(grid)
    filled = np.where(valid, grid, 0.0)
    coords = np.vstack([rows, cols])
    num = ndimage.map_coordinates(filled, coords, order=1, mode="nearest")
    den = ndimage.map_coordinates(valid.astype(np.float64), coords, order=1, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0.5, num / den, np.nan)


def _ranges(tri: SeedTriangulation, rows: np.ndarray, cols: np.ndarray, scale: int,
            margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle initial disparity and integer search range at a pyramid level."""
    bounds = tri.evaluate(cols * scale, rows * scale)
    margin_level = max(1.0, margin / scale)
    low = np.floor(bounds.low / scale - margin_level).astype(np.int64)
    high = np.ceil(bounds.high / scale + margin_level).astype(np.int64)
    return bounds.disparity / scale, low, high


def _densify_points(rows: np.ndarray, cols: np.ndarray, disparity: np.ndarray,
                    correlation: np.ndarray, cell: int) -> tuple[np.ndarray, np.ndarray]:
    """Best-correlated accepted match per ``cell`` × ``cell`` block: new seeds."""
    if rows.size == 0:
        return np.zeros((0, 2)), np.zeros(0)
    key = (rows // cell) * (int(cols.max()) // cell + 1) + cols // cell
    order = np.lexsort((-correlation, key))
    _, first = np.unique(key[order], return_index=True)
    chosen = order[first]
    return np.column_stack([cols[chosen], rows[chosen]]).astype(np.float64), disparity[chosen]


class _Matched(NamedTuple):
    """NCC + LSM outcome for N template centres (see :func:`_match_points`)."""

    tried: np.ndarray  # (N,) bool: NCC found a peak good enough for LSM
    accepted: np.ndarray  # (N,) bool
    disparity: np.ndarray  # (N,) float64, NaN unless accepted
    correlation: np.ndarray  # (N,) float64, LSM correlation where tried
    sigma: np.ndarray  # (N,) float64, NaN unless accepted
    shape: np.ndarray  # (N, 5) float64: y_right − row, a1, a2, b1, b2; NaN unless accepted
    time_ncc: float
    time_lsm: float


def _match_points(left: np.ndarray, right: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                  low: np.ndarray, high: np.ndarray, *, template: int, threshold: float,
                  max_vertical: float, weighting: float, left_valid: np.ndarray,
                  right_valid: np.ndarray) -> _Matched:
    """NCC inside [low, high], LSM from the NCC peak, then the acceptance tests."""
    started = time.perf_counter()
    ncc = ncc_search(left, right, rows, cols, low, high, template=template,
                     left_valid=left_valid, right_valid=right_valid)
    t_ncc = time.perf_counter() - started
    has = np.isfinite(ncc.disparity) & (ncc.correlation >= threshold - LSM_NCC_SLACK)
    lsm = lsm_match(left, right, rows[has], cols[has], cols[has] - ncc.disparity[has],
                    rows[has].astype(np.float64), template=template,
                    left_valid=left_valid, right_valid=right_valid,
                    give_up_below=threshold - LSM_NCC_SLACK, weighting=weighting)
    d = cols[has] - lsm.x_right
    ok = ((lsm.status == CONVERGED) & (lsm.correlation >= threshold)
          & (np.abs(lsm.y_right - rows[has]) <= max_vertical)
          & (d >= low[has] - 1.0) & (d <= high[has] + 1.0))
    accepted = np.zeros(rows.size, dtype=bool)
    accepted[has] = ok
    disparity = np.full(rows.size, np.nan)
    disparity[np.nonzero(has)[0][ok]] = d[ok]
    correlation = np.full(rows.size, np.nan)
    correlation[has] = lsm.correlation
    sigma = np.full(rows.size, np.nan)
    sigma[np.nonzero(has)[0][ok]] = lsm.sigma_x[ok]
    shape = np.full((rows.size, 5), np.nan)
    shape[np.nonzero(has)[0][ok]] = np.column_stack([lsm.y_right - rows[has],
                                                     lsm.affine])[ok]
    return _Matched(has, accepted, disparity, correlation, sigma, shape, t_ncc,
                    time.perf_counter() - started - t_ncc)


def _usable_levels(shape: tuple[int, int], levels: int, template: int) -> int:
    """Levels whose coarsest image is still at least 3 templates wide and tall."""
    usable = levels
    while usable > 1 and min(shape) / 2 ** (usable - 1) < 3 * template:
        usable -= 1
    return usable


def match(left: np.ndarray, right: np.ndarray, *, template: int = 17, threshold: float = 0.9,
          grid_spacing: int = 2, levels: int = 3, search_margin: float = 2.0, rounds: int = 2,
          seed_points: tuple[np.ndarray, np.ndarray] | None = None,
          disparity_range: tuple[float, float] | None = None, use_sift: bool = True,
          max_vertical: float = 1.5, weighting: float = 3.0, refine: int = 1) -> MatchResult:
    """Dense disparity of a rectified pair by seeds, triangles, pyramid NCC and LSM.

    Parameters
    ----------
    left, right : (H, W) float
        Rectified grey images of the same shape (any DN scale); NaN = nodata (never
        matched).  Not modified.
    template : int
        Template size (odd, 9 … 25 pixels; 17 in the HiRISE study).
    threshold : float
        Acceptance threshold on the LSM correlation coefficient (0.9 in the HiRISE
        study; 0.8 relaxed).
    grid_spacing : int
        Pixels between template centres at full resolution (1 = every pixel); other
        pixels are interpolated between four accepted nodes that agree within
        ``INTERPOLATION_TOLERANCE`` px, or matched themselves where some corner was
        accepted but the interpolation does not hold.
    levels : int
        Pyramid levels (reduced when the coarsest would be narrower than 3 templates).
    search_margin : float
        Pixels added on both sides of the triangle's vertex-disparity range (scaled
        with the pyramid level, at least 1 level pixel).
    rounds : int
        Densification rounds after the first full-resolution pass.
    seed_points : ((N, 2), (N, 2)) float, optional
        Prior matches (x, y) in the left and right image (e.g. rectify.npz inliers).
    disparity_range : (float, float), optional
        Disparity range for the corner seed search when there are no SIFT/prior seeds.
    use_sift : bool
        Detect SIFT seeds (:mod:`demtool.imaging.features`).
    max_vertical : float
        Largest row offset (pixels) of an accepted match in the rectified pair.
    weighting : float
        Gaussian observation weights of σ = ``weighting`` pixels in LSM (0: uniform,
        Grün's ordinary LSM as in the HiRISE study).  Centre weighting reduces the
        smoothing of relief finer than the template; the acceptance test then uses
        the weighted correlation coefficient.
    refine : int
        Inverse-compositional Gauss–Newton iterations that refine every accepted
        disparity with its own template and the affine shape of its LSM solution
        (interpolated between the nodes for interpolated pixels;
        :func:`demtool.match.between.polish`); 0 = off.  Completeness is unchanged: a
        refinement that fails keeps the disparity it started from.

    Returns
    -------
    MatchResult

    Raises
    ------
    ParameterError
        Bad option values, images of different shapes, seeds outside the images.
    ProcessingError
        No valid pixel, or fewer than 3 usable seeds (no texture, no overlap).
    """
    started = time.perf_counter()
    check_parameters(template, threshold, grid_spacing, levels, search_margin, rounds,
                     weighting, refine)
    left = np.asarray(left, dtype=np.float64)
    right = np.asarray(right, dtype=np.float64)
    if left.ndim != 2 or right.ndim != 2:
        raise ParameterError(f"images must be 2-D, got shapes {left.shape} and {right.shape}")
    if left.shape != right.shape:
        raise ParameterError(f"the rectified images differ in size: left {left.shape[1]} x "
                             f"{left.shape[0]}, right {right.shape[1]} x {right.shape[0]}")
    if min(left.shape) < template + 4:
        raise ParameterError(f"images of {left.shape[1]} x {left.shape[0]} pixels are too small "
                             f"for a {template}-pixel template")
    left_valid = np.isfinite(left)
    if not left_valid.any() or not np.isfinite(right).any():
        raise ProcessingError("an image has no valid (finite) pixel")
    if seed_points is not None:
        seed_points = check_seed_points(seed_points[0], seed_points[1], left.shape, right.shape)

    seed_threshold = min(threshold, 0.8)
    seeds = find_seeds(left, right, template=template, min_correlation=seed_threshold,
                       max_vertical=max_vertical, prior=seed_points,
                       disparity_range=disparity_range, use_sift=use_sift)
    if len(seeds.points) < 3:
        raise ProcessingError(
            f"only {len(seeds.points)} reliable seed match(es) between the images "
            f"(candidates: {seeds.counts}); at least 3 are needed — are the images "
            "textured, overlapping and rectified?")
    log.info("seeds: %d verified (%s), disparity %.1f … %.1f px", len(seeds.points),
             ", ".join(f"{k} {v}" for k, v in seeds.counts.items()),
             seeds.disparity.min(), seeds.disparity.max())
    tri = SeedTriangulation(seeds.points, seeds.disparity)
    t_seeds = time.perf_counter() - started

    n_levels = _usable_levels(left.shape, levels, template)
    if n_levels < levels:
        log.info("pyramid: %d level(s) instead of %d (image too small)", n_levels, levels)
    pyr_left = build_pyramid(left, n_levels)
    pyr_right = build_pyramid(right, n_levels)

    # --- coarse levels: NCC on every pixel, the result guides the next level -------
    guide: np.ndarray | None = None
    level_stats = []
    for level in range(n_levels - 1, 0, -1):
        img_l, ok_l = pyr_left[level]
        img_r, ok_r = pyr_right[level]
        scale = 2 ** level
        rows, cols = np.nonzero(ok_l)
        _, low, high = _ranges(tri, rows, cols, scale, search_margin)
        low, high = _narrow(low, high, guide, rows, cols)
        ncc = ncc_search(img_l, img_r, rows, cols, low, high, template=template,
                         left_valid=ok_l, right_valid=ok_r)
        good = np.isfinite(ncc.disparity) & (ncc.correlation >= COARSE_MIN_CORRELATION)
        grid = np.full(img_l.shape, np.nan)
        grid[rows[good], cols[good]] = ncc.disparity[good]
        median = _nan_median3(grid)
        grid[np.abs(grid - median) > 1.0] = np.nan  # isolated blunders
        guide = grid
        level_stats.append({"level": level, "shape": list(img_l.shape),
                            "matched_percent": round(100.0 * np.isfinite(grid).sum()
                                                     / max(1, ok_l.sum()), 2)})
    t_pyramid = time.perf_counter() - started - t_seeds

    # --- full resolution: NCC + LSM on the grid nodes, then densification rounds -------
    height, width = left.shape
    node_rows = np.arange(0, height, grid_spacing)
    node_cols = np.arange(0, width, grid_spacing)
    rr, cc = np.meshgrid(node_rows, node_cols, indexing="ij")
    rows_all, cols_all = rr.ravel(), cc.ravel()
    node_disp = np.full(rows_all.size, np.nan)
    node_corr = np.full(rows_all.size, np.nan)
    node_sigma = np.full(rows_all.size, np.nan)
    node_shape = np.full((rows_all.size, 5), np.nan)  # y_right − row, a1, a2, b1, b2
    # only nodes whose template lies on valid left pixels can ever match
    half = template // 2
    table = integral_invalid(left_valid)
    r0, r1 = rows_all - half, rows_all + half + 1
    c0, c1 = cols_all - half, cols_all + half + 1
    inside = (r0 >= 0) & (c0 >= 0) & (r1 <= height) & (c1 <= width)
    todo = np.zeros(rows_all.size, dtype=bool)
    todo[inside] = (table[r1[inside], c1[inside]] - table[r0[inside], c1[inside]]
                    - table[r1[inside], c0[inside]] + table[r0[inside], c0[inside]]) == 0
    candidates = int(todo.sum())
    round_stats = []
    right_valid = np.isfinite(right)
    tried_low = np.full(rows_all.size, np.iinfo(np.int64).min)
    tried_high = np.full(rows_all.size, np.iinfo(np.int64).min)
    for round_index in range(rounds + 1):
        idx = np.nonzero(todo)[0]
        rows, cols = rows_all[idx], cols_all[idx]
        _, low, high = _ranges(tri, rows, cols, 1, search_margin)
        if round_index == 0:
            low, high = _narrow(low, high, guide, rows, cols)
        else:  # a node whose search range did not change would fail the same way
            changed = (low != tried_low[idx]) | (high != tried_high[idx])
            idx, rows, cols, low, high = (a[changed] for a in (idx, rows, cols, low, high))
        if idx.size == 0:
            break
        tried_low[idx] = low
        tried_high[idx] = high
        found = _match_points(left, right, rows, cols, low, high, template=template,
                              threshold=threshold, max_vertical=max_vertical,
                              weighting=weighting, left_valid=left_valid,
                              right_valid=right_valid)
        accepted = found.accepted
        node_corr[idx[found.tried]] = found.correlation[found.tried]
        node_disp[idx[accepted]] = found.disparity[accepted]
        node_sigma[idx[accepted]] = found.sigma[accepted]
        node_shape[idx[accepted]] = found.shape[accepted]
        todo[idx[accepted]] = False
        round_stats.append({"round": round_index, "evaluated": int(idx.size),
                            "lsm_tried": int(found.tried.sum()),
                            "accepted": int(accepted.sum()),
                            "mean_search_range_px": round(float(np.mean(high - low + 1)), 2),
                            "time_ncc_s": round(found.time_ncc, 3),
                            "time_lsm_s": round(found.time_lsm, 3)})
        log.info("round %d: %d of %d nodes accepted", round_index, int(accepted.sum()), idx.size)
        if round_index == rounds or not accepted.any():
            break
        done = np.isfinite(node_disp)
        new_points, new_disp = _densify_points(rows_all[done], cols_all[done], node_disp[done],
                                               node_corr[done], max(template, grid_spacing))
        tri = SeedTriangulation(np.concatenate([seeds.points, new_points]),
                                np.concatenate([seeds.disparity, new_disp]))

    shape_nodes = (node_rows.size, node_cols.size)
    if grid_spacing == 1:
        disparity = node_disp.reshape(shape_nodes)
        correlation = node_corr.reshape(shape_nodes)
        sigma = node_sigma.reshape(shape_nodes)
        warp = node_shape.reshape(*shape_nodes, 5)
        edge_stats = None
    else:
        disparity, correlation, sigma, warp, edge_stats = _fill_between_nodes(
            left, right, node_disp.reshape(shape_nodes), node_corr.reshape(shape_nodes),
            node_sigma.reshape(shape_nodes), node_shape.reshape(*shape_nodes, 5), tri,
            grid_spacing=grid_spacing,
            template=template, threshold=threshold, max_vertical=max_vertical,
            weighting=weighting, search_margin=search_margin, left_valid=left_valid,
            right_valid=right_valid)
    refine_stats = None
    if refine:
        disparity, correlation, refine_stats = polish(
            left, right, disparity, correlation, warp, template=template, weighting=weighting,
            threshold=threshold, max_vertical=max_vertical, iterations=refine,
            left_valid=left_valid, right_valid=right_valid)
    disparity = np.where(left_valid, disparity, np.nan)
    accepted_pixels = int(np.isfinite(disparity).sum())
    completeness = 100.0 * accepted_pixels / int(left_valid.sum())
    accepted_nodes = int(np.isfinite(node_disp).sum())
    finite_d = disparity[np.isfinite(disparity)]
    summary = {
        "completeness_percent": round(completeness, 3),
        "accepted_pixels": accepted_pixels,
        "valid_left_pixels": int(left_valid.sum()),
        "grid_nodes": int(rows_all.size),
        "grid_nodes_matchable": candidates,
        "grid_nodes_accepted": accepted_nodes,
        "seeds": len(seeds.points),
        "seed_counts": seeds.counts,
        "pyramid_levels": n_levels,
        "levels": level_stats,
        "rounds": round_stats,
        "between_nodes": edge_stats,
        "refined": refine_stats,
        "disparity_min": float(finite_d.min()) if finite_d.size else None,
        "disparity_max": float(finite_d.max()) if finite_d.size else None,
        "median_sigma_px": float(np.nanmedian(node_sigma)) if accepted_nodes else None,
        "mean_correlation_accepted": (float(np.nanmean(node_corr[np.isfinite(node_disp)]))
                                      if accepted_nodes else None),
        "time_seeds_s": round(t_seeds, 3),
        "time_pyramid_s": round(t_pyramid, 3),
        "time_total_s": round(time.perf_counter() - started, 3),
    }
    log.info("completeness %.1f %% (%d of %d valid pixels), median sigma %s px",
             completeness, accepted_pixels, int(left_valid.sum()), summary["median_sigma_px"])
    return MatchResult(disparity=disparity.astype(np.float32),
                       correlation=correlation.astype(np.float32),
                       sigma=sigma.astype(np.float32), seeds=seeds, summary=summary)


def _fill_between_nodes(left: np.ndarray, right: np.ndarray, node_disp: np.ndarray,
                        node_corr: np.ndarray, node_sigma: np.ndarray,
                        node_shape: np.ndarray, tri: SeedTriangulation, *,
                        grid_spacing: int, template: int, threshold: float,
                        max_vertical: float, weighting: float, search_margin: float,
                        left_valid: np.ndarray, right_valid: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """Every pixel from the node grid: interpolated where smooth, matched at edges.

    Between four accepted nodes that agree within ``INTERPOLATION_TOLERANCE`` the
    disparity (and correlation, sigma) is bilinear; a pixel with at least one accepted
    corner but no smooth interpolation (a disparity edge, the border of the accepted
    area) is matched itself, searching its corners' disparities ± ``PYRAMID_RADIUS``
    inside its triangle range.  Pixels with no accepted corner stay NaN.
    """
    weights, corners, smooth, edge = between_nodes(node_disp, left.shape, grid_spacing,
                                                   INTERPOLATION_TOLERANCE)
    disparity, correlation, sigma, warp = (spread_nodes(nodes, weights, corners, smooth)
                                           for nodes in (node_disp, node_corr, node_sigma,
                                                         node_shape))
    rows, cols = np.nonzero(edge & left_valid)
    stats = {"interpolated": int((smooth & left_valid).sum()), "matched": int(rows.size),
             "accepted": 0}
    if rows.size == 0:
        return disparity, correlation, sigma, warp, stats
    values = node_disp.ravel()[corners[:, rows, cols]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        corner_low = np.floor(np.nanmin(values, axis=0) - PYRAMID_RADIUS).astype(np.int64)
        corner_high = np.ceil(np.nanmax(values, axis=0) + PYRAMID_RADIUS).astype(np.int64)
    _, low, high = _ranges(tri, rows, cols, 1, search_margin)
    new_low, new_high = np.maximum(low, corner_low), np.minimum(high, corner_high)
    inside = new_low <= new_high
    low, high = np.where(inside, new_low, corner_low), np.where(inside, new_high, corner_high)
    found = _match_points(left, right, rows, cols, low, high, template=template,
                          threshold=threshold, max_vertical=max_vertical, weighting=weighting,
                          left_valid=left_valid, right_valid=right_valid)
    disparity[rows, cols] = found.disparity
    correlation[rows, cols] = found.correlation
    sigma[rows, cols] = found.sigma
    warp[rows, cols] = found.shape
    stats.update(accepted=int(found.accepted.sum()), time_ncc_s=round(found.time_ncc, 3),
                 time_lsm_s=round(found.time_lsm, 3))
    log.info("between nodes: %d pixels interpolated, %d of %d edge pixels matched",
             stats["interpolated"], stats["accepted"], rows.size)
    return disparity, correlation, sigma, warp, stats


def _narrow(low: np.ndarray, high: np.ndarray, guide: np.ndarray | None, rows: np.ndarray,
            cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Narrow a level's triangle range to ±PYRAMID_RADIUS around the coarser result."""
    if guide is None:
        return low, high
    estimate = 2.0 * _sample_coarse(guide, rows / 2.0, cols / 2.0)
    have = np.isfinite(estimate)
    est = np.where(have, estimate, 0.0)
    new_low = np.maximum(low, np.floor(est - PYRAMID_RADIUS).astype(np.int64))
    new_high = np.minimum(high, np.ceil(est + PYRAMID_RADIUS).astype(np.int64))
    use = have & (new_low <= new_high)
    return np.where(use, new_low, low), np.where(use, new_high, high)
