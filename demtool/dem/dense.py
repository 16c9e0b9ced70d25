"""A BAM DEM densified from the block's matched pairs (``dem --points B --dense D R``).

The bundle's tie points measure well under 5 % of the target's cells; the rest of a
BAM DEM is gap filling.  A dense source — a disparity map of a pair of the same block
(``sgm`` or ``match`` on ``rectify``'s uncalibrated rectification) — measures most
cells.  Its disparities are mapped back to the pair's original pixels (inverse
rectification, :func:`demtool.dem.disparity.disparity_correspondences`) and triangulated
with **the bundle's own cameras** of the pair, so the dense points land in the bundle's
frame and scale; they are then projected into the bundle's target camera and turned
into heights by the same convention as the tie points (:mod:`demtool.dem.points`):
metric heights along the target's view for an aligned bundle, eq. 2 of the NavCam study
otherwise — with the *tie points'* mean depth as the reference depth, so that one
model depth gives one height whichever source measured it.

Merge (:func:`merge_samples`): each source gets the robust local-median test on its
own; then a tie that disagrees with the dense surface in its cell (by more than the
threshold times the local dense NMAD, floored by the spread of all tie − dense
differences) is dropped — one sample against the many around it, so the many decide
(on the 512 × 512 synthetic NavCam scene of ``make demo`` the ties a consensus test
dropped had 0.76 m RMS error where the dense samples had 0.34 m) — and a tie that
agrees is averaged with the dense height of its cell at equal weight: two independent
measurements, neither known to be the better (there, at the 6259 cells both measured,
ties alone 0.234 m RMSE, dense alone 0.226 m, their mean 0.184 m).  Where the pair
does not see, the ties measure alone, tested among themselves as in the sparse route.

A pair need not include the target: its points are projected into the target like the
tie points.  Points the target cannot see (behind relief, from an oblique pair) are not
removed by a visibility test (only the local-median test may drop them, where they are
few among their neighbours), so on steep ground seen obliquely prefer pairs that include
the target.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.dem.disparity import (
    disparity_correspondences,
    sample_bilinear,
    screen_triangulation,
    triangulate,
)
from demtool.dem.grid import local_median_inliers, splat_bilinear, splat_median
from demtool.dem.points import (
    heights_along_view,
    heights_from_relative_depth,
    project_to_target,
    target_samples,
)
from demtool.dem.routes import MIN_SAMPLES, DemResult, OutlierOptions, finish_dem
from demtool.errors import InputError, ProcessingError
from demtool.logs import get_logger
from demtool.sensors.pinhole import PinholeCamera

log = get_logger(__name__)

#: a pair whose rays, through the bundle's cameras, miss each other by more than this
#: median (pixels of the left image's footprint) is not a pair of this block: ``rectify``
#: keeps matches within 1 px of their epipolar line, so a pair of the block misses by less
MAX_MEDIAN_GAP_PX = 2.0


@dataclass(frozen=True)
class DensePair:
    """A matched pair of the block: a disparity map and its rectification.

    Attributes
    ----------
    disparity : (Hr, Wr) float
        Left rectified frame, ``x_right = x_left − d``, pixels; NaN = invalid.
    H_left, H_right : (3, 3) float
        Rectification homographies (original → rectified) of ``rectify.npz``.
    left, right : str
        Image names of the pair (``rectify.npz`` ``left_name``/``right_name``).
    label : str
        How reports name the pair (its disparity file).
    """

    disparity: np.ndarray
    H_left: np.ndarray
    H_right: np.ndarray
    left: str
    right: str
    label: str = ""


@dataclass(frozen=True)
class Samples:
    """Height samples in the target image: positions (N, 2) px and heights (N,) metres."""

    pixels: np.ndarray
    heights: np.ndarray


def dense_samples(pair: DensePair, cameras: Mapping[str, PinholeCamera], target: str, *,
                  aligned: bool, distortion: Sequence[float] = (0.0, 0.0),
                  mean_depth: float | None = None, distance_m: float | None = None,
                  max_ray_gap: float | None = None) -> tuple[Samples, dict[str, Any]]:
    """Height samples of one pair's disparities in the bundle's target image.

    Parameters
    ----------
    pair : DensePair
    cameras : mapping of name → PinholeCamera
        The bundle's cameras (model frame; metres when ``aligned``), with their lenses.
    target : str
        Name of the bundle's target image (the DEM's frame).
    aligned : bool
        Metric bundle: heights along the target's view.  Otherwise eq. 2 of the
        NavCam study with ``distance_m`` and the tie points' ``mean_depth``.
    distortion : (2,) float
        Radial terms (k1, k2) of the target camera (``bundle.npz`` ``distortion``).
    mean_depth : float, optional
        Mean target depth of the tie points, model units (required when not aligned).
    distance_m : float, optional
        Spacecraft–surface distance D, metres (required when not aligned).
    max_ray_gap : float, optional
        Largest miss between the two rays, model units (default
        :func:`demtool.dem.disparity.screen_triangulation`'s).

    Returns
    -------
    samples : Samples
    report : dict
        ``disparities``, ``behind_camera``, ``rejected_ray_gap``, ``max_ray_gap``,
        ``in_target`` (counts of the pair).

    Raises
    ------
    InputError
        Not a pair of this block: its images are not in the bundle, no disparity
        triangulates in front of both cameras, or the rays miss each other by a median
        of more than :data:`MAX_MEDIAN_GAP_PX` pixels.
    ProcessingError
        No valid disparity, or no triangulated point lands in the target image.
    ValueError
        ``mean_depth`` or ``distance_m`` missing for an unaligned bundle.
    """
    missing = [name for name in (pair.left, pair.right) if name not in cameras]
    if missing:
        raise InputError(f"{pair.label}: the pair's image {', '.join(missing)} is not "
                         f"registered in the bundle ({', '.join(cameras)}); is it a pair of "
                         "this block?")
    left, right = cameras[pair.left], cameras[pair.right]
    corr = disparity_correspondences(pair.disparity, pair.H_left, pair.H_right)
    points, gap = triangulate(corr, left, right)
    screen = screen_triangulation(points, gap, left, right, max_ray_gap=max_ray_gap)
    camera = cameras[target]
    kept = points[screen.keep]
    report: dict[str, Any] = {"pair": pair.label, "left": pair.left, "right": pair.right,
                              "disparities": int(len(points)), "behind_camera": screen.behind,
                              "rejected_ray_gap": screen.rejected_gap,
                              "max_ray_gap": screen.max_gap}
    if len(kept) == 0:
        raise InputError(f"{pair.label}: no disparity triangulates in front of both "
                         f"cameras {pair.left} and {pair.right} of the bundle; is it a "
                         "pair of this block?")
    footprint = left.depth(kept) / left.focal_px
    gap_px = float(np.median(gap[screen.keep] / footprint))
    report["median_ray_gap_px"] = gap_px
    if not gap_px <= MAX_MEDIAN_GAP_PX:
        raise InputError(f"{pair.label}: through the bundle's cameras of {pair.left} and "
                         f"{pair.right}, the pair's rays miss each other by {gap_px:.3g} px "
                         f"(median; a pair of this block: < {MAX_MEDIAN_GAP_PX:g} px): the "
                         "disparity is not of this bundle's images")
    try:
        pixels, depth, index = project_to_target(kept, camera, distortion)
    except ProcessingError as error:
        raise ProcessingError(f"{pair.label}: no overlap with the target {target}: "
                              f"{error}") from None
    if aligned:
        heights = heights_along_view(kept[index], camera)
    else:
        if mean_depth is None or distance_m is None:
            raise ValueError("an unaligned bundle needs the tie points' mean depth and the "
                             "spacecraft-surface distance")
        heights = heights_from_relative_depth(depth, distance_m, mean_depth=mean_depth)
    report["in_target"] = int(len(heights))
    return Samples(pixels=pixels, heights=heights), report


def merge_samples(ties: Samples, dense: Samples, shape: tuple[int, int], *,
                  neighbours: int = 16, threshold: float = 3.0
                  ) -> tuple[np.ndarray, dict[str, Any]]:
    """Merge tie and dense height samples on the target grid (see the module's text).

    Each source first gets the local-median test on its own (Westerweel & Scarano 2005,
    :func:`demtool.dem.grid.local_median_inliers`: ties among ties, as the sparse BAM
    route, dense among dense); the dense samples are resampled by
    :func:`demtool.dem.grid.splat_bilinear`, the ties by cell median
    (:func:`demtool.dem.grid.splat_median`).  Then every tie whose cell the dense source
    also measured is tested against it: the tie is dropped when
    ``|tie − dense| > threshold · max(local NMAD, NMAD(tie − dense))`` — the local NMAD
    of the dense samples nearest the tie (steep or rough ground), floored by the robust
    spread of all tie − dense differences (how well the two sources agree at all).
    A surviving tie is moved to its cell's centre along the dense surface (the dense
    height at the centre plus the tie's difference from the dense surface at its own
    sub-pixel position, so it does not bring the half-pixel rounding of
    :func:`~demtool.dem.grid.splat_median` with it) and averaged, at equal weight, with
    the dense height of the cell: two independent measurements of one cell, neither
    known to be the better one.  Ties where the dense source has no value measure their
    cells alone, as in the sparse route.

    Parameters
    ----------
    ties, dense : Samples
    shape : (H, W)
        The target's grid.
    neighbours, threshold : int, float
        The outlier test's (:class:`demtool.dem.routes.OutlierOptions`).

    Returns
    -------
    measured : (H, W) float64
        Heights, NaN where neither source measured.
    report : dict
        Outliers of each source (``tie_outliers`` counts both tests), cells measured by
        ties and by dense samples, and the agreement of ties with the dense surface
        (median and NMAD of tie − dense at the cells both measured, metres, before the
        disagreeing ties are dropped).
    """
    from demtool.dem.grid import local_median_statistics
    from demtool.imaging.robust import nmad

    keep_ties = local_median_inliers(ties.pixels, ties.heights, neighbours=neighbours,
                                     threshold=threshold)
    keep_dense = local_median_inliers(dense.pixels, dense.heights, neighbours=neighbours,
                                      threshold=threshold)
    dense_grid, _ = splat_bilinear(dense.pixels[keep_dense], dense.heights[keep_dense], shape)
    height, width = shape
    cells = np.rint(ties.pixels).astype(np.int64)
    inside = ((cells[:, 0] >= 0) & (cells[:, 0] < width) & (cells[:, 1] >= 0)
              & (cells[:, 1] < height))
    dense_at_cell = np.full(len(ties.heights), np.nan)
    dense_at_cell[inside] = dense_grid[cells[inside, 1], cells[inside, 0]]
    dense_at_tie = sample_bilinear(dense_grid, ties.pixels)  # at the tie's own position
    both = keep_ties & np.isfinite(dense_at_tie) & np.isfinite(dense_at_cell)
    difference = ties.heights[both] - dense_at_tie[both]
    agreement = {"tie_minus_dense_median_m": float(np.median(difference)) if both.any()
                 else None,
                 "tie_minus_dense_nmad_m": float(nmad(difference)) if both.sum() > 1 else None}
    if both.sum() > 1 and threshold > 0:
        pixels = np.concatenate([dense.pixels[keep_dense], ties.pixels[both]])
        heights = np.concatenate([dense.heights[keep_dense], ties.heights[both]])
        at = np.arange(int(keep_dense.sum()), len(heights))
        _, local_nmad = local_median_statistics(pixels, heights, neighbours=neighbours, at=at)
        scale = np.maximum(local_nmad, max(agreement["tie_minus_dense_nmad_m"], 1e-12))
        disagree = np.flatnonzero(both)[np.abs(difference) > threshold * scale]
        keep_ties[disagree] = False
    # A tie moved to its cell's centre along the dense surface: its height there is the
    # dense height plus the tie's own difference from the dense surface at its position.
    at_centre = ties.heights.copy()
    at_centre[both] = dense_at_cell[both] + difference
    tie_grid, _ = splat_median(ties.pixels[keep_ties], at_centre[keep_ties], shape)
    tie_cells, dense_cells = np.isfinite(tie_grid), np.isfinite(dense_grid)
    measured = np.where(tie_cells, tie_grid, dense_grid)
    shared = tie_cells & dense_cells
    measured[shared] = 0.5 * (tie_grid[shared] + dense_grid[shared])
    report = {
        "tie_outliers": int(len(keep_ties) - keep_ties.sum()),
        "dense_outliers": int(len(keep_dense) - keep_dense.sum()),
        "cells_ties": int(tie_cells.sum()),
        "cells_dense": int(dense_cells.sum()),
        "cells_dense_only": int((dense_cells & ~tie_cells).sum()),
        "cells_both": int(shared.sum()),
        **agreement,
    }
    return measured, report


def densified_measurements(points: np.ndarray, cameras: Mapping[str, PinholeCamera],
                           target: str, pairs: Sequence[DensePair], *, aligned: bool,
                           distance_m: float | None = None,
                           distortion: Sequence[float] = (0.0, 0.0),
                           neighbours: int = 16, threshold: float = 3.0,
                           max_ray_gap: float | None = None
                           ) -> tuple[np.ndarray, dict[str, Any]]:
    """The measured grid of a BAM DEM densified by the block's pairs (before filling).

    Parameters
    ----------
    points : (N, 3) float
        The bundle's tie points (model frame; metres when ``aligned``).
    cameras : mapping of name → PinholeCamera
        The bundle's cameras.
    target : str
        The DEM's frame: the bundle's target image.
    pairs : sequence of DensePair
        At least one pair of the block.
    aligned, distance_m, distortion
        As :func:`demtool.dem.points.target_samples`.
    neighbours, threshold : int, float
        The outlier test.
    max_ray_gap : float, optional
        Triangulation screen of the pairs, model units.

    Returns
    -------
    measured : (H, W) float64
        NaN where unmeasured.
    report : dict
        Counts per source and per pair (JSON-serialisable).
    """
    camera = cameras[target]
    ties = target_samples(points, camera, aligned=aligned, distance_m=distance_m,
                          distortion=distortion)
    mean_depth = float(np.mean(ties.depth))
    dense_parts, pair_reports = [], []
    for pair in pairs:
        samples, report = dense_samples(pair, cameras, target, aligned=aligned,
                                        distortion=distortion, mean_depth=mean_depth,
                                        distance_m=distance_m, max_ray_gap=max_ray_gap)
        dense_parts.append(samples)
        pair_reports.append(report)
        log.info("%s (%s–%s): %d disparities, %d behind a camera, %d rays missing by more "
                 "than %.3g dropped, %d land in %s", report["pair"], pair.left, pair.right,
                 report["disparities"], report["behind_camera"], report["rejected_ray_gap"],
                 report["max_ray_gap"], report["in_target"], target)
    dense = Samples(np.concatenate([s.pixels for s in dense_parts]),
                    np.concatenate([s.heights for s in dense_parts]))
    measured, merge = merge_samples(Samples(ties.pixels, ties.heights), dense,
                                    (camera.height, camera.width), neighbours=neighbours,
                                    threshold=threshold)
    report = {
        "points_total": int(len(points)),
        "points_in_target": int(len(ties.heights)),
        "median_depth": float(np.median(ties.depth)),
        "dense_pairs": pair_reports,
        "dense_in_target": int(len(dense.heights)),
        **merge,
        "outliers_removed": merge["tie_outliers"] + merge["dense_outliers"],
        "cells_measured": int(np.isfinite(measured).sum()),
    }
    return measured, report


def dem_from_points_dense(points: np.ndarray, cameras: Mapping[str, PinholeCamera],
                          target: str, pairs: Sequence[DensePair], *, aligned: bool,
                          distance_m: float | None = None,
                          distortion: Sequence[float] = (0.0, 0.0),
                          outliers: OutlierOptions | None = None, median_px: int = 0,
                          max_ray_gap: float | None = None) -> DemResult:
    """Dense BAM DEM: bundle tie points densified by the block's matched pairs.

    :func:`densified_measurements`, then the gap filling and median filter of every
    route (:func:`demtool.dem.routes.finish_dem`).  Parameters as there; ``outliers``
    the local-median test (default :class:`~demtool.dem.routes.OutlierOptions`'s),
    ``median_px`` the median filter (0 = none).

    Returns
    -------
    DemResult
        (H, W) of the target camera; heights in the BAM convention (metres, positive
        toward the camera; eq. 2 for an unaligned bundle).

    Raises
    ------
    InputError
        A pair that is not of this block (names, sizes, rays that miss).
    ProcessingError
        No tie point in the target, a pair with no overlap, too few samples.
    """
    outliers = outliers or OutlierOptions()
    measured, report = densified_measurements(
        points, cameras, target, pairs, aligned=aligned, distance_m=distance_m,
        distortion=distortion, neighbours=outliers.neighbours, threshold=outliers.threshold,
        max_ray_gap=max_ray_gap)
    if report["cells_measured"] < MIN_SAMPLES:
        raise ProcessingError(f"only {report['cells_measured']} cells measured in the target "
                              f"image; at least {MIN_SAMPLES} are needed to interpolate a DEM")
    report["height_scale"] = ("metric (aligned bundle)" if aligned
                              else "eq. 2 (relative depth, the tie points' mean depth)")
    return finish_dem(measured, median_px, report)
