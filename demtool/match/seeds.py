"""Seed matches of a rectified pair: SIFT, Förstner corners, LSM verification.

Seeds anchor the dense matcher: their disparities, triangulated, give every pixel an
initial disparity and a search range (:mod:`demtool.match.triangles`).  They come
from three sources, all verified the same way:

1. SIFT matches (Lowe 2004: ratio test, mutual nearest neighbours) searched only
   among the keypoints on the same row within ``max_vertical`` pixels — the
   epipolar constraint of a rectified pair, applied directly instead of estimating
   F by RANSAC (:func:`match_on_rows`);
2. Förstner interest points of the left image (Förstner & Gülch 1987), matched by
   NCC along the same row of the right image inside the disparity range of the
   other seeds, kept when the match is mutual (the right point matches back to
   within one pixel of the left one);
3. optional prior matches (e.g. the inlier matches of ``rectify.npz``).

Every candidate is then refined by least-squares matching (:mod:`demtool.match.lsm`)
and kept only when it converges with a correlation of at least the seed threshold
and stays on its row; finally seeds whose disparity disagrees with the median of
their Delaunay neighbours are removed as blunders.

References
----------
Förstner, W., Gülch, E. (1987). A fast operator for detection and precise location
    of distinct points, corners and centres of circular features. ISPRS
    Intercommission Workshop, Interlaken, 281-305.
Lowe, D. G. (2004). Distinctive image features from scale-invariant keypoints.
    IJCV 60(2), 91-110.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from demtool.errors import ParameterError, ProcessingError
from demtool.imaging.robust import nmad
from demtool.logs import get_logger
from demtool.match.lsm import lsm_match
from demtool.match.lsm_base import CONVERGED
from demtool.match.ncc import ncc_search
from demtool.match.triangles import SeedTriangulation

log = get_logger(__name__)


class Seeds(NamedTuple):
    """Verified seed matches.

    Attributes
    ----------
    points : (N, 2) float64
        Seed positions (x, y) in the left image: integer pixel centres, pixels.
    disparity : (N,) float64
        LSM sub-pixel disparity (``x_right = x_left − d``), pixels.
    correlation : (N,) float64
        LSM correlation coefficient.
    counts : dict of str to int
        Candidates per source and survivors of each check (for the log and sidecar).
    """

    points: np.ndarray
    disparity: np.ndarray
    correlation: np.ndarray
    counts: dict


def check_seed_points(points_left: np.ndarray, points_right: np.ndarray,
                      left_shape: tuple[int, int], right_shape: tuple[int, int],
                      what: str = "seed points") -> tuple[np.ndarray, np.ndarray]:
    """Check prior seed matches: shapes, finite values, inside both images.

    Parameters
    ----------
    points_left, points_right : (N, 2) float
        Matches (x, y) in the left and right (rectified) images.
    left_shape, right_shape : (int, int)
        (H, W) of the images.
    what : str
        Name of the seeds' origin for messages (e.g. the file).

    Returns
    -------
    (N, 2) float64, (N, 2) float64

    Raises
    ------
    ParameterError
        Shapes differ, a value is not finite, or a point lies outside its image.
    """
    left = np.asarray(points_left, dtype=np.float64)
    right = np.asarray(points_right, dtype=np.float64)
    if left.ndim != 2 or left.shape[1:] != (2,) or left.shape != right.shape:
        raise ParameterError(f"{what}: left and right seed arrays must both be (N, 2), got "
                             f"{left.shape} and {right.shape}")
    if not (np.isfinite(left).all() and np.isfinite(right).all()):
        raise ParameterError(f"{what}: seed coordinates contain NaN or infinity")
    for name, pts, (height, width) in (("left", left, left_shape),
                                       ("right", right, right_shape)):
        outside = ((pts[:, 0] < -0.5) | (pts[:, 0] > width - 0.5)
                   | (pts[:, 1] < -0.5) | (pts[:, 1] > height - 0.5))
        if outside.any():
            raise ParameterError(
                f"{what}: {int(outside.sum())} of {len(pts)} {name} seed points lie outside "
                f"the {width} x {height} {name} image (first at x={pts[outside][0, 0]:.1f}, "
                f"y={pts[outside][0, 1]:.1f}); are they from this (rectified) pair?")
    return left, right


def forstner_points(image: np.ndarray, *, spacing: int = 24, window: int = 5,
                    min_roundness: float = 0.5, min_weight_factor: float = 1.0,
                    border: int = 8) -> np.ndarray:
    """Förstner interest points, at most one per ``spacing`` × ``spacing`` cell.

    The structure tensor ``N`` of the image gradients, summed over a ``window``, gives
    the weight ``w = det N / tr N`` (size of the error ellipse's inverse) and the
    roundness ``q = 4 det N / tr² N`` (Förstner & Gülch 1987, eqs. 5-6).  Points are
    local maxima of ``w`` with ``q >= min_roundness`` and ``w`` above
    ``min_weight_factor`` times the mean weight; the strongest per cell is kept.

    Parameters
    ----------
    image : (H, W) float
        Grey image; NaN = nodata (no point within ``border`` of nodata).

    Returns
    -------
    (N, 2) int64
        Points (x, y) = (column, row), strongest first.
    """
    from scipy import ndimage

    valid = np.isfinite(image)
    fill = float(np.mean(image[valid])) if valid.any() else 0.0
    work = np.where(valid, image, fill).astype(np.float64)
    gy, gx = np.gradient(work)
    nxx = ndimage.uniform_filter(gx * gx, window)
    nyy = ndimage.uniform_filter(gy * gy, window)
    nxy = ndimage.uniform_filter(gx * gy, window)
    det = nxx * nyy - nxy * nxy
    trace = nxx + nyy
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(trace > 0, det / trace, 0.0)
        roundness = np.where(trace > 0, 4.0 * det / trace ** 2, 0.0)
    usable = ndimage.minimum_filter(valid.astype(np.uint8), size=2 * border + 1, mode="constant",
                                    cval=0).astype(bool)
    mean_weight = float(weight[usable].mean()) if usable.any() else 0.0
    peaks = (weight == ndimage.maximum_filter(weight, size=window)) & usable
    peaks &= (roundness >= min_roundness) & (weight > min_weight_factor * mean_weight)
    peaks &= weight > 0
    rows, cols = np.nonzero(peaks)
    if rows.size == 0:
        return np.zeros((0, 2), np.int64)
    strength = weight[rows, cols]
    cell = (rows // spacing) * (image.shape[1] // spacing + 1) + cols // spacing
    order = np.lexsort((-strength, cell))
    _, first = np.unique(cell[order], return_index=True)
    chosen = order[first]
    chosen = chosen[np.argsort(-strength[chosen])]
    return np.column_stack([cols[chosen], rows[chosen]]).astype(np.int64)


def sift_candidates(left: np.ndarray, right: np.ndarray, *, max_vertical: float,
                    max_features: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches on the same row (rectified epipolar constraint).

    Returns
    -------
    (N, 2) float64, (N, 2) float64
        Matched points (x, y) in the left and right images.
    """
    from demtool.imaging import features

    feats_left = features.detect_sift(left, max_features=max_features)
    feats_right = features.detect_sift(right, max_features=max_features)
    if len(feats_left) == 0 or len(feats_right) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    pairs = match_on_rows(feats_left.points, feats_left.descriptors, feats_right.points,
                          feats_right.descriptors, max_vertical=max_vertical, ratio=0.8)
    return (feats_left.points[pairs[:, 0]].astype(np.float64),
            feats_right.points[pairs[:, 1]].astype(np.float64))


@njit(cache=True, parallel=True)
def _band_nearest(y_query, query, y_sorted, reference, band, index, best, second):
    """Two nearest ``reference`` descriptors (squared L2) within ``band`` rows of each query.

    ``y_sorted`` (the reference rows) is ascending; ``index`` −1 where none is in band.
    """
    for i in prange(query.shape[0]):
        lo = np.searchsorted(y_sorted, y_query[i] - band, side="left")
        hi = np.searchsorted(y_sorted, y_query[i] + band, side="right")
        d1 = np.inf
        d2 = np.inf
        j1 = -1
        for j in range(lo, hi):
            d = 0.0
            for k in range(query.shape[1]):
                t = query[i, k] - reference[j, k]
                d += t * t
            if d < d1:
                d2 = d1
                d1 = d
                j1 = j
            elif d < d2:
                d2 = d
        index[i] = j1
        best[i] = d1
        second[i] = d2


def _nearest_on_rows(y_query: np.ndarray, query: np.ndarray, y_reference: np.ndarray,
                     reference: np.ndarray, band: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    order = np.argsort(y_reference, kind="stable")
    index = np.empty(len(query), np.int64)
    best = np.empty(len(query))
    second = np.empty(len(query))
    _band_nearest(np.ascontiguousarray(y_query, np.float64), np.ascontiguousarray(query),
                  np.ascontiguousarray(y_reference[order], np.float64),
                  np.ascontiguousarray(reference[order]), float(band), index, best, second)
    found = index >= 0
    index[found] = order[index[found]]
    return index, best, second


def match_on_rows(points_left: np.ndarray, descriptors_left: np.ndarray,
                  points_right: np.ndarray, descriptors_right: np.ndarray, *,
                  max_vertical: float, ratio: float = 0.8) -> np.ndarray:
    """Descriptor matches of a rectified pair, searched only along the same row.

    Lowe's (2004) ratio test and the mutual nearest-neighbour check of
    :func:`demtool.imaging.features.match_descriptors`, with the candidates of a keypoint
    restricted to the other image's keypoints within ``max_vertical`` rows (the
    epipolar constraint of a rectified pair): a few dozen candidates per keypoint
    instead of every keypoint, and no false match from another row.

    Parameters
    ----------
    points_left, points_right : (N, 2), (M, 2) float
        Keypoints (x, y), pixels.
    descriptors_left, descriptors_right : (N, D), (M, D) float32
    max_vertical : float
        Largest row difference, pixels.
    ratio : float
        Ratio-test threshold on the distances (nearest < ratio × second nearest in
        the band; a lone candidate passes).

    Returns
    -------
    (K, 2) int64
        Index pairs (left, right), sorted by the left index.
    """
    a = np.ascontiguousarray(descriptors_left, dtype=np.float32)
    b = np.ascontiguousarray(descriptors_right, dtype=np.float32)
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    y_left = np.asarray(points_left, np.float64)[:, 1]
    y_right = np.asarray(points_right, np.float64)[:, 1]
    forward, best, second = _nearest_on_rows(y_left, a, y_right, b, max_vertical)
    backward, _, _ = _nearest_on_rows(y_right, b, y_left, a, max_vertical)
    keep = (forward >= 0) & ~(best >= ratio**2 * second)  # inf second: a lone candidate
    left_index = np.nonzero(keep)[0]
    right_index = forward[keep]
    mutual = backward[right_index] == left_index
    return np.column_stack([left_index[mutual], right_index[mutual]]).astype(np.int64)


def corner_candidates(left: np.ndarray, right: np.ndarray, d_min: int, d_max: int, *,
                      template: int, spacing: int, min_correlation: float) -> np.ndarray:
    """Förstner points of the left image matched by mutual NCC along the same row.

    Returns
    -------
    (N, 3) float64
        x, y (left, integer pixel) and disparity (pixels) of the mutual matches.
    """
    corners = forstner_points(left, spacing=spacing, border=template // 2 + 1)
    if len(corners) == 0:
        return np.zeros((0, 3))
    cols, rows = corners[:, 0], corners[:, 1]
    n = len(rows)
    forward = ncc_search(left, right, rows, cols, np.full(n, d_min), np.full(n, d_max),
                         template=template)
    good = np.isfinite(forward.disparity) & (forward.correlation >= min_correlation)
    rows, cols, disparity = rows[good], cols[good], forward.disparity[good]
    x_right = np.rint(cols - disparity).astype(np.int64)
    m = len(rows)
    # back-matching: right template searched in the left image (x_left = x_right + d)
    backward = ncc_search(right, left, rows, x_right, np.full(m, -d_max), np.full(m, -d_min),
                          template=template)
    mutual = np.abs(x_right - backward.disparity - cols) <= 1.0
    return np.column_stack([cols[mutual], rows[mutual], disparity[mutual]]).astype(np.float64)


def verify_seeds(left: np.ndarray, right: np.ndarray, points_left: np.ndarray,
                 points_right: np.ndarray, *, template: int, min_correlation: float,
                 max_vertical: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refine candidate matches by LSM and keep the converged, correlated, on-row ones.

    Returns
    -------
    points : (N, 2) float64
        Left integer pixel centres (x, y) of the survivors.
    disparity, correlation : (N,) float64
    """
    centres = np.rint(points_left)
    offset = centres - points_left  # move the right point along with the rounding
    result = lsm_match(left, right, centres[:, 1].astype(np.int64), centres[:, 0].astype(np.int64),
                       points_right[:, 0] + offset[:, 0], points_right[:, 1] + offset[:, 1],
                       template=template, max_shift=2.0)
    ok = ((result.status == CONVERGED) & (result.correlation >= min_correlation)
          & (np.abs(result.y_right - centres[:, 1]) <= max_vertical))
    return centres[ok], centres[ok, 0] - result.x_right[ok], result.correlation[ok]


def remove_blunders(points: np.ndarray, disparity: np.ndarray, *, tolerance: float = 3.0,
                    rounds: int = 3) -> np.ndarray:
    """Mask of seeds consistent with their Delaunay neighbours.

    A seed is a blunder when its disparity differs from the median of its Delaunay
    neighbours by more than ``max(tolerance, 3 × 1.4826 × MAD)`` of those differences;
    blunders are removed and the test repeated up to ``rounds`` times.

    Returns
    -------
    (N,) bool
        True for the seeds kept.
    """
    keep = np.ones(len(points), dtype=bool)
    for _ in range(rounds):
        if keep.sum() < 4:
            break
        try:
            tri = SeedTriangulation(points[keep], disparity[keep])
        except ProcessingError:
            break
        if len(tri) != keep.sum():  # duplicates collapsed: skip the test
            break
        deviation = disparity[keep] - tri.neighbour_median()
        bad = np.abs(deviation) > max(tolerance, 3.0 * nmad(deviation))
        if not bad.any():
            break
        idx = np.nonzero(keep)[0]
        keep[idx[bad]] = False
    return keep


def find_seeds(left: np.ndarray, right: np.ndarray, *, template: int = 17,
               min_correlation: float = 0.8, max_vertical: float = 1.5,
               prior: tuple[np.ndarray, np.ndarray] | None = None,
               disparity_range: tuple[float, float] | None = None, use_sift: bool = True,
               corner_spacing: int | None = None) -> Seeds:
    """Seed matches of a rectified pair (SIFT + Förstner/NCC + prior), LSM-verified.

    Parameters
    ----------
    left, right : (H, W) float
        Rectified grey images; NaN = nodata.
    template : int
        LSM/NCC template size (odd), pixels.
    min_correlation : float
        LSM correlation a seed must reach.
    max_vertical : float
        Largest row difference of a match (pixels): the rectified epipolar constraint.
    prior : ((N, 2), (N, 2)) float, optional
        Known matches (x, y) in left and right (checked with
        :func:`check_seed_points` by the caller).  With 50 or more, SIFT is skipped.
    disparity_range : (float, float), optional
        Range for the corner search when SIFT and the prior give too few matches
        (default ±W/2).
    use_sift : bool
        Detect SIFT matches.
    corner_spacing : int, optional
        One Förstner point per cell of this size (default 2 × template).

    Returns
    -------
    Seeds
        Possibly empty (the caller decides whether that is an error).
    """
    counts: dict[str, int] = {}
    cand_left = [np.zeros((0, 2))]
    cand_right = [np.zeros((0, 2))]
    if prior is not None:
        cand_left.append(np.asarray(prior[0], dtype=np.float64))
        cand_right.append(np.asarray(prior[1], dtype=np.float64))
        counts["prior"] = len(prior[0])
    if use_sift and counts.get("prior", 0) < 50:
        sift_left, sift_right = sift_candidates(left, right, max_vertical=max_vertical)
        cand_left.append(sift_left)
        cand_right.append(sift_right)
        counts["sift"] = len(sift_left)
    pts_left = np.concatenate(cand_left)
    pts_right = np.concatenate(cand_right)
    if len(pts_left) >= 5:
        d = pts_left[:, 0] - pts_right[:, 0]
        low, high = np.percentile(d, [2, 98])
        pad = max(4.0, 0.25 * (high - low))
        d_min, d_max = int(np.floor(low - pad)), int(np.ceil(high + pad))
    elif disparity_range is not None:
        d_min, d_max = int(np.floor(disparity_range[0])), int(np.ceil(disparity_range[1]))
    else:
        d_min, d_max = -(left.shape[1] // 2), left.shape[1] // 2
    corners = corner_candidates(left, right, d_min, d_max, template=template,
                                spacing=corner_spacing or 2 * template,
                                min_correlation=min_correlation)
    counts["corners"] = len(corners)
    pts_left = np.concatenate([pts_left, corners[:, :2]])
    pts_right = np.concatenate([pts_right, corners[:, :2] - np.column_stack(
        [corners[:, 2], np.zeros(len(corners))])])
    counts["candidates"] = len(pts_left)
    if len(pts_left) == 0:
        empty = np.zeros(0)
        return Seeds(np.zeros((0, 2)), empty, empty, counts)
    points, disparity, correlation = verify_seeds(
        left, right, pts_left, pts_right, template=template,
        min_correlation=min_correlation, max_vertical=max_vertical)
    counts["lsm_verified"] = len(points)
    # several candidates on one pixel: keep the best correlated one
    order = np.lexsort((-correlation, points[:, 1], points[:, 0]))
    _, first = np.unique(points[order], axis=0, return_index=True)
    chosen = np.sort(order[first])
    points, disparity, correlation = points[chosen], disparity[chosen], correlation[chosen]
    keep = remove_blunders(points, disparity)
    counts["kept"] = int(keep.sum())
    log.debug("seeds: %s", counts)
    return Seeds(points[keep], disparity[keep], correlation[keep], counts)
