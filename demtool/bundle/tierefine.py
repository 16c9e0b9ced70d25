"""Least-squares refinement of multi-view tie observations (issue 14).

SIFT keypoints are centres of difference-of-Gaussian blobs, found independently in
every image.  On rough, shaded, sloping terrain a blob is the projection of no single
surface point: its centre moves with perspective (foreshortening differs from view to
view), so the observations of one track disagree by errors of 0.2–0.3 px RMS that are
tied to the terrain, and a block tied to a reference DEM follows them (a common offset
of its cameras of several metres at orbital scale).  Photogrammetric tie-point
pipelines therefore re-measure every track by area-based least-squares matching
against one reference observation (Grün 1985; Förstner & Gülch 1987 select the points,
LSM measures them): the track's reference observation is moved to the nearest pixel
centre of its image, a square template around it is matched into each other image of
the track by affine LSM (:func:`demtool.match.lsm.lsm_match`, 6 geometric + 2
radiometric parameters, Keys' cubic resampling, observations weighted by a Gaussian of
σ = 3 px about the centre so the match describes the centre more than the window's
mean plane), and the LSM position of the template centre replaces the SIFT position.
Observations whose LSM fails, correlates poorly, or moves more than ``max_move_px``
from the SIFT prediction are dropped; tracks left with one view go.  On rendered
orbital blocks this halves the observations' error against the truth and the block's
offset (docs/stages/bundle.md, issue 14).

References
----------
Grün, A. (1985). Adaptive least squares correlation: a powerful image matching
    technique. South African Journal of Photogrammetry, Remote Sensing and
    Cartography 14(3), 175-187.
Förstner, W., Gülch, E. (1987). A fast operator for detection and precise location of
    distinct points, corners and centres of circular features. ISPRS Intercommission
    Workshop, Interlaken, 281-305.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from demtool.bundle.priors import Observations
from demtool.errors import ParameterError
from demtool.logs import get_logger

log = get_logger(__name__)


class RefineReport(NamedTuple):
    """What :func:`refine_observations` did.

    Attributes
    ----------
    observations_in, observations_out : int
        Observations before and after (reference observations included).
    points_in, points_out : int
        Tracks before and after.
    dropped_failed, dropped_moved, dropped_correlation : int
        Non-reference observations dropped because LSM did not converge, because it
        moved more than ``max_move_px`` from the SIFT prediction, or because its
        correlation was below ``min_correlation``.
    median_move_px : float
        Median distance between the refined and the SIFT-predicted positions, pixels.
    """

    observations_in: int
    observations_out: int
    points_in: int
    points_out: int
    dropped_failed: int
    dropped_moved: int
    dropped_correlation: int
    median_move_px: float

    def as_dict(self) -> dict:
        return dict(self._asdict())


def reference_observations(obs: Observations) -> np.ndarray:
    """Index (P,) of each track's reference observation: the one in the
    lowest-numbered image (the block's first image, the target, where it sees the
    track)."""
    n_points = obs.point_count
    key = obs.image.astype(np.int64) * (len(obs.image) + 1) + np.arange(len(obs.image))
    best = np.full(n_points, np.iinfo(np.int64).max)
    np.minimum.at(best, obs.point, key)
    return (best % (len(obs.image) + 1)).astype(np.int64)


def refine_observations(images: Sequence[np.ndarray], obs: Observations, *,
                        template: int = 15, weighting: float = 3.0,
                        max_move_px: float = 1.0, min_correlation: float = 0.7
                        ) -> tuple[Observations, RefineReport]:
    """Re-measure every track by affine LSM against its reference observation.

    Parameters
    ----------
    images : sequence of (H, W) arrays
        Grey images of the block (any DN scale; NaN = no data), as matched.
    obs : Observations
        Tie observations (CSM image coordinates: first pixel centre at 0.5), e.g. from
        :func:`demtool.bundle.ties.tie_points`.
    template : int
        LSM template size, pixels (odd, ≥ 5).
    weighting : float
        Gaussian weighting of the template (σ, pixels; 0 = uniform, Grün's LSM).  On
        rendered orbital blocks 3 px left the block closer to the truth than uniform
        weights (docs/stages/bundle.md, issue 14).
    max_move_px : float
        Largest distance between an LSM position and its SIFT prediction (the SIFT
        observation moved by the reference's snap to its pixel centre), pixels.
    min_correlation : float
        Least correlation coefficient of an accepted LSM match.

    Raises
    ------
    ParameterError
        ``template``, ``max_move_px`` or ``min_correlation`` out of range.

    Returns
    -------
    observations : Observations
        Refined observations, tracks renumbered 0 … P'-1; each reference observation
        at a pixel centre of its image, the others at LSM positions.
    report : RefineReport
    """
    from demtool.match.lsm import lsm_match
    from demtool.match.lsm_base import CONVERGED

    if template < 5 or template % 2 == 0:
        raise ParameterError(f"tie refinement: template must be odd and >= 5, got {template}")
    if max_move_px <= 0:
        raise ParameterError(f"tie refinement: max_move_px must be > 0, got {max_move_px}")
    if not -1.0 <= min_correlation <= 1.0:
        raise ParameterError("tie refinement: min_correlation must be in [-1, 1], got "
                             f"{min_correlation}")
    ref = reference_observations(obs)
    ref_of = ref[obs.point]
    is_ref = ref_of == np.arange(len(obs.image))
    # the reference observation snapped to its pixel centre (CSM: centre of pixel
    # (r, c) is (r + 0.5, c + 0.5)); the template is centred there
    ref_row = np.floor(obs.line[ref]).astype(np.int64)
    ref_col = np.floor(obs.sample[ref]).astype(np.int64)
    snap_line = ref_row + 0.5 - obs.line[ref]
    snap_sample = ref_col + 0.5 - obs.sample[ref]
    line = obs.line.copy()
    sample = obs.sample.copy()
    line[ref] = ref_row + 0.5
    sample[ref] = ref_col + 0.5
    keep = is_ref.copy()
    failed = moved_far = weak = 0
    moves = []
    others = np.flatnonzero(~is_ref)
    ref_image = obs.image[ref_of[others]]
    images64 = [np.asarray(im, dtype=np.float64) for im in images]
    for a in np.unique(ref_image):
        for b in np.unique(obs.image[others[ref_image == a]]):
            k = others[(ref_image == a) & (obs.image[others] == b)]
            p = obs.point[k]
            # predicted position of the template centre: the SIFT observation moved by
            # the reference's snap (the local affine map is close to identity)
            x0 = obs.sample[k] - 0.5 + snap_sample[p]
            y0 = obs.line[k] - 0.5 + snap_line[p]
            res = lsm_match(images64[a], images64[b], ref_row[p], ref_col[p], x0, y0,
                            template=template, weighting=weighting,
                            max_shift=max(2.0 * max_move_px, 1.0))
            ok = res.status == CONVERGED
            move = np.hypot(res.x_right - x0, res.y_right - y0)
            near = ok & (move <= max_move_px)
            good = near & (res.correlation >= min_correlation)
            failed += int((~ok).sum())
            moved_far += int((ok & ~near).sum())
            weak += int((near & ~good).sum())
            moves.append(move[good])
            sample[k[good]] = res.x_right[good] + 0.5
            line[k[good]] = res.y_right[good] + 0.5
            keep[k[good]] = True
    refined = Observations(obs.image, obs.point, line, sample).subset(keep)
    all_moves = np.concatenate(moves) if moves else np.zeros(0)
    report = RefineReport(
        observations_in=int(len(obs.image)), observations_out=int(len(refined.image)),
        points_in=obs.point_count, points_out=refined.point_count,
        dropped_failed=failed, dropped_moved=moved_far, dropped_correlation=weak,
        median_move_px=float(np.median(all_moves)) if len(all_moves) else float("nan"))
    log.info("LSM refinement: %d of %d observations kept (%d tracks of %d), median move "
             "%.3f px", report.observations_out, report.observations_in,
             report.points_out, report.points_in, report.median_move_px)
    return refined, report
