"""Map-projected stereo: matching two orthoimages on one map grid, and the way back
from a map-grid disparity to raw image coordinates.

Line scanners have no single centre of projection, so the pair is map-projected onto
a smooth prior surface (``demtool mapproject``) and matched there, as ASP's
map-projected stereo does (Beyer, Alexandrov & McMichael 2018, *The Ames Stereo
Pipeline*, Earth and Space Science 5, §2.3).  The orthoimages of a cross-track
(roll) pair differ by an east–west parallax proportional to the height above the
prior; demtool searches it in 1-D along map x (the Middlebury convention
``x_right = x_left − d`` in map columns) and refuses a pair whose residual north–south
disparity is not small (it needs a 2-D search or an affine alignment, future work).

Both matchers, ``sgm`` and ``match``, take the same route: :func:`is_ortho_pair` tells
two orthoimages of ``demtool mapproject`` apart, :func:`ortho_pair_matches` checks their
grids and sets the search range from their SIFT matches (which ``match`` also takes as
its seeds).

Pure functions: arrays (or rasters as read) in, arrays out; no file I/O.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from demtool.errors import ProcessingError
from demtool.logs import get_logger

log = get_logger(__name__)

#: the largest median |dy| (map cells) of the matches accepted for a 1-D search
MAX_DY_MEDIAN_PX = 0.5
#: the largest spread (NMAD) of dy (map cells) accepted for a 1-D search
MAX_DY_SPREAD_PX = 1.0
#: fewest matches that set a search range
MIN_MATCHES = 20
#: orthoimages of more cells are matched in windows (:func:`sift_windows`): SIFT on a
#: whole 64 Mpx orthoimage (a full-width 12 000-line LRO NAC) holds ~15 GB; on 10.7 Mpx
#: it peaked at 2.9 GB
SIFT_WINDOWS_ABOVE_CELLS = 16 * 2**20
SIFT_WINDOW_CELLS = 1024  # side of a window, cells
SIFT_WINDOWS = 16  # windows spread evenly over the image (16 Mpx in all)
#: the largest constant cross offset (median dy, map cells) that sgm takes out by shifting
#: the right ortho along map y before matching: the relative pointing error of two
#: satellite images (a Pléiades pair's RPCs: ~1 px; s2p corrects it the same way, a
#: translation of the right image from SIFT matches).  Larger offsets are refused (the pair
#: needs a 2-D alignment, or its models a correction).
MAX_DY_SHIFT_PX = 2.0
#: the disparity's tag: map rows the right ortho was shifted by (``y_right = y_left +
#: shift``); ``dem --mapprojected`` applies it
ROW_SHIFT_TAG = "ortho_row_shift_px"


def row_shift_of(tags) -> float:
    """The right ortho's row shift a disparity's tags record (0 when none)."""
    try:
        return float(tags.get(ROW_SHIFT_TAG, 0.0))
    except (TypeError, ValueError):
        return 0.0


def shift_rows(image: np.ndarray, shift: float) -> np.ndarray:
    """``image`` sampled at rows ``r + shift`` (linear between rows; NaN beyond the
    image or next to NaN), same shape, float32."""
    image = np.asarray(image, dtype=np.float32)
    rows = np.arange(image.shape[0], dtype=np.float64) + float(shift)
    r0 = np.floor(rows).astype(np.int64)
    t = (rows - r0).astype(np.float32)[:, None]
    inside = (r0 >= 0) & (r0 + 1 < image.shape[0]) | (t[:, 0] == 0) & (r0 >= 0) & (
        r0 < image.shape[0])
    a = image[np.clip(r0, 0, image.shape[0] - 1)]
    b = image[np.clip(r0 + 1, 0, image.shape[0] - 1)]
    out = (1 - t) * a + t * b
    out[~inside] = np.nan
    return out.astype(np.float32)


class OrthoRange(NamedTuple):
    """The search range of two orthoimages and their residual cross disparity.

    low, high : float, map cells, disparity range (``x_left − x_right``) with margin
    dy_median : float, map cells, median of ``y_right − y_left`` of the matches
    dy_spread : float, map cells, 1.4826 × median absolute deviation of dy
    matches : int, number of matches used
    aligned : bool, dy small enough for a 1-D search along map x
    points_left, points_right : (N, 2) float64, map cells (x = column, y = row)
        The matches kept (gross mismatches dropped), left and right.
    """

    low: float
    high: float
    dy_median: float
    dy_spread: float
    matches: int
    aligned: bool
    points_left: np.ndarray
    points_right: np.ndarray


def ortho_disparity_range(left: np.ndarray, right: np.ndarray, *, margin: float = 2.0,
                          max_dy_median: float = MAX_DY_MEDIAN_PX,
                          max_dy_spread: float = MAX_DY_SPREAD_PX,
                          ratio: float = 0.8) -> OrthoRange:
    """Search range along map x from SIFT matches between two orthoimages.

    Matches are SIFT keypoints (Lowe 2004) paired by the ratio test and a mutual check
    (orthoimages of more than ``SIFT_WINDOWS_ABOVE_CELLS`` cells: in
    :func:`sift_windows` of both, at full resolution, so memory stays bounded; the
    matcher widens a range that a window missed, :mod:`demtool.sgm.widen`);
    matches more than 5 NMAD (at least 3 cells) away from the median displacement in
    either direction are dropped as gross mismatches, then the range is the 1st–99th
    percentile of ``x_left − x_right`` widened by ``margin`` cells
    (:func:`demtool.rectify.core.robust_disparity_range`).

    Parameters
    ----------
    left, right : (H, W) float
        Orthoimages on the same map grid, NaN = not seen.
    margin : float
        Widening of the range on each side, map cells.
    max_dy_median, max_dy_spread : float
        Limits of the residual cross disparity (map cells) for ``aligned``.
    ratio : float
        Lowe's ratio-test threshold.

    Returns
    -------
    OrthoRange

    Raises
    ------
    ProcessingError
        Fewer than :data:`MIN_MATCHES` matches.
    """
    from demtool.rectify.core import robust_disparity_range

    windows = [(0, 0, left.shape[0], left.shape[1])] if left.size <= SIFT_WINDOWS_ABOVE_CELLS \
        else sift_windows(left.shape)
    found = [_window_matches(left, right, w, ratio) for w in windows]
    counts = np.sum([f[2] for f in found], axis=0)
    if counts[0] < MIN_MATCHES or counts[1] < MIN_MATCHES:
        raise ProcessingError(f"only {counts[0]} and {counts[1]} SIFT keypoints")
    pa = np.concatenate([f[0] for f in found])
    pb = np.concatenate([f[1] for f in found])
    dx = pa[:, 0] - pb[:, 0]
    dy = pb[:, 1] - pa[:, 1]
    keep = np.ones(dx.size, bool)
    for values in (dx, dy):
        if values.size:
            med = np.median(values)
            nmad = 1.4826 * np.median(np.abs(values - med))
            keep &= np.abs(values - med) <= max(5.0 * nmad, 3.0)
    if keep.sum() < MIN_MATCHES:
        raise ProcessingError(f"only {int(keep.sum())} consistent SIFT matches "
                              f"(of {dx.size}); at least {MIN_MATCHES} set the search range")
    dx, dy, pa, pb = dx[keep], dy[keep], pa[keep], pb[keep]
    low, high = robust_disparity_range(dx, margin=margin)
    dy_median = float(np.median(dy))
    dy_spread = float(1.4826 * np.median(np.abs(dy - dy_median)))
    aligned = abs(dy_median) <= max_dy_median and dy_spread <= max_dy_spread
    log.info("%d ortho matches: disparity %.2f … %.2f cells, dy median %.3f, spread %.3f",
             dx.size, low, high, dy_median, dy_spread)
    return OrthoRange(float(low), float(high), dy_median, dy_spread, int(dx.size), aligned,
                      pa, pb)


def is_ortho_pair(left, right) -> bool:
    """True when both rasters (``demtool.io.Raster`` or ``RasterInfo``) are orthoimages
    written by ``demtool mapproject`` (they carry its sensor tag), or both are ISIS
    ``cam2map`` cubes of a line-scan camera (:mod:`demtool.sensors.isis_cam2map`)."""
    from demtool.mapproject.surface import SENSOR_TAG
    from demtool.sensors.isis_cam2map import is_cam2map_cube

    if SENSOR_TAG in left.tags and SENSOR_TAG in right.tags:
        return True
    return is_cam2map_cube(getattr(left, "path", None)) and \
        is_cam2map_cube(getattr(right, "path", None))


def sift_windows(shape: tuple[int, int], *, side: int = SIFT_WINDOW_CELLS,
                 count: int = SIFT_WINDOWS) -> list[tuple[int, int, int, int]]:
    """About ``count`` windows ``(row0, col0, rows, cols)`` of ``side`` cells spread
    evenly over an image of ``shape`` (a grid with the image's aspect, first and last
    windows at the edges), where a large pair of orthoimages is matched."""
    height, width = shape
    rows = max(1, min(count, round(math.sqrt(count * height / max(width, 1)))))
    cols = max(1, count // rows)
    h, w = min(side, height), min(side, width)
    r0 = np.linspace(0, height - h, rows).round().astype(int) if rows > 1 else [0]
    c0 = np.linspace(0, width - w, cols).round().astype(int) if cols > 1 else [0]
    return [(int(r), int(c), h, w) for r in r0 for c in c0]


def _window_matches(left: np.ndarray, right: np.ndarray, window: tuple[int, int, int, int],
                    ratio: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """SIFT matches (left, right points in image cells) of one window of both images,
    and the two keypoint counts."""
    from demtool.imaging.features import detect_sift, match_descriptors

    r0, c0, h, w = window
    part_left, part_right = left[r0:r0 + h, c0:c0 + w], right[r0:r0 + h, c0:c0 + w]
    a = detect_sift(part_left, mask=np.isfinite(part_left))
    b = detect_sift(part_right, mask=np.isfinite(part_right))
    counts = (len(a.points), len(b.points))
    if min(counts) < 2:
        return np.empty((0, 2)), np.empty((0, 2)), counts
    pairs = match_descriptors(a.descriptors, b.descriptors, ratio=ratio, mutual=True)
    offset = np.array([c0, r0], dtype=np.float64)
    return (a.points[pairs[:, 0]].astype(np.float64) + offset,
            b.points[pairs[:, 1]].astype(np.float64) + offset, counts)


def ortho_pair_matches(left, right, *, stage: str, allow_shift: bool = False
                       ) -> tuple[OrthoRange, str, dict]:
    """The search range of two orthoimages as read, checked for a 1-D search along map x.

    Parameters
    ----------
    left, right : demtool.io.Raster
        Orthoimages (``data`` (H, W) float, NaN = not seen; ``transform``, ``crs``,
        ``path``).
    stage : str
        The matcher (``"sgm"``, ``"match"``), named in the refusal.
    allow_shift : bool
        The matcher shifts the right ortho by a constant cross offset up to
        :data:`MAX_DY_SHIFT_PX` (then ``stats`` holds :data:`ROW_SHIFT_TAG`).

    Returns
    -------
    found : OrthoRange
        From :func:`ortho_disparity_range`.
    source : str
        Where the range came from, for the sidecar.
    stats : dict
        ``ortho_matches``, ``ortho_dy_median_px``, ``ortho_dy_spread_px`` for the sidecar.

    Raises
    ------
    InputError
        The orthoimages are on different map grids, or their matches are offset
        north–south (a 1-D search along map x would not find them: the pair needs a 2-D
        alignment).
    ProcessingError
        Too few matches to set the range.
    """
    from demtool.errors import InputError

    if (left.transform != right.transform or str(left.crs) != str(right.crs)
            or left.data.shape != right.data.shape):
        raise InputError(f"{left.path} and {right.path}: the orthoimages are on different "
                         "map grids; map-project the right one with --grid-like LEFT")
    try:
        found = ortho_disparity_range(left.data, right.data)
    except ProcessingError as exc:
        raise ProcessingError(f"{left.path} and {right.path}: cannot set the search range "
                              f"from matches ({exc}); give the disparity range "
                              "(--min-disparity and --num-disparities for sgm)") from None
    stats = {"ortho_matches": found.matches, "ortho_dy_median_px": found.dy_median,
             "ortho_dy_spread_px": found.dy_spread}
    if not found.aligned and allow_shift and found.dy_spread <= MAX_DY_SPREAD_PX and \
            abs(found.dy_median) <= MAX_DY_SHIFT_PX:
        log.info("the right ortho is offset by %.3f rows (spread %.3f): shifted before "
                 "matching (relative pointing of the pair)", found.dy_median, found.dy_spread)
        stats[ROW_SHIFT_TAG] = found.dy_median
        return found, f"SIFT matches of the orthoimages ({found.matches})", stats
    if not found.aligned:
        raise InputError(
            f"{left.path} and {right.path}: the orthoimages' matches are offset "
            f"north-south by {found.dy_median:.2f} cells (spread {found.dy_spread:.2f}; "
            f"limits {MAX_DY_MEDIAN_PX:g} and {MAX_DY_SPREAD_PX:g}): {stage} searches along "
            "map x only, the pair needs a 2-D alignment (mapproject the left one with "
            "--pair-sensor RIGHT_MODEL to turn the grid along the parallax)")
    return found, f"SIFT matches of the orthoimages ({found.matches})", stats


def map_cells_xy(transform, rows: np.ndarray, cols: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates of (fractional) cell indices; the centre of cell (r, c) is at
    ``(c + 0.5, r + 0.5)`` in the transform's pixel coordinates.

    rows, cols : (N,) float, cells; returns (x, y), metres in the grid's CRS.
    """
    t = transform
    cc = np.asarray(cols, dtype=np.float64) + 0.5
    rr = np.asarray(rows, dtype=np.float64) + 0.5
    return t.a * cc + t.b * rr + t.c, t.d * cc + t.e * rr + t.f


def disparity_cells(disparity: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left and right cells of every valid map-grid disparity.

    disparity : (H, W) float, map cells, ``x_right = x_left − d``, NaN = invalid.

    Returns
    -------
    rows, left_cols, right_cols : (N,) float64, cells (the right cell is
    ``(row, col − d)``, fractional).
    """
    rows, cols = np.nonzero(np.isfinite(disparity))
    d = disparity[rows, cols].astype(np.float64)
    return rows.astype(np.float64), cols.astype(np.float64), cols - d


#: how far (map cells) a right cell may lie beyond the right orthoimage's columns: the
#: half cell of its edge pixel plus a subpixel refinement's overshoot
RIGHT_CELL_MARGIN = 1.0


def check_right_cells(disparity_path: Any, right_path: Any, left_cols: np.ndarray,
                      right_cols: np.ndarray, width: int) -> None:
    """Refuse disparities whose right cell ``col − d`` is off the right orthoimage.

    A matcher found every right cell inside the right orthoimage (``0 ≤ col − d ≤
    width − 1`` within :data:`RIGHT_CELL_MARGIN`); one outside it is not a disparity
    between these orthoimages (issue 46: a disparity of 1e27 cells put the DEM elsewhere).

    Raises
    ------
    InputError
        One line naming the disparity, how many cells and the worst disparity value.
    """
    from demtool.errors import InputError

    with np.errstate(invalid="ignore"):
        off = ~((right_cols >= -RIGHT_CELL_MARGIN)
                & (right_cols <= width - 1 + RIGHT_CELL_MARGIN))
    if off.any():
        d = (left_cols - right_cols)[off]
        worst = float(d[np.argmax(np.abs(d))])
        raise InputError(f"{disparity_path}: {int(off.sum())} disparities (up to {worst:.4g} "
                         f"map cells) put the right cell outside the {width} columns of "
                         f"{right_path}; not a disparity between these orthoimages")


def raw_coordinates(sensor, crs, transform, rows: np.ndarray, cols: np.ndarray,
                    heights: np.ndarray, *, tolerance: float | None = None,
                    origins: bool = False):
    """Raw image (line, sample) of map cells on a surface, through a sensor model.

    Parameters
    ----------
    sensor : demtool.sensors.base.SensorModel
    crs, transform
        The map grid (projected CRS on the body's sphere).
    rows, cols : (N,) float
        Cells (fractional allowed).
    heights : (N,) float
        The surface the orthoimage was projected on at those cells, metres above the
        body's reference sphere (NaN = none).
    tolerance : float, optional
        Largest interpolation error accepted, image pixels (default
        :data:`demtool.mapproject.lattice.TOLERANCE_PX`; 0: every cell projected exactly).
    origins : bool
        Also each cell's ray origin (``PointCoordinates.origin``).

    Returns
    -------
    demtool.mapproject.lattice.PointCoordinates
        ``line, sample`` (N,) float64, CSM image coordinates (NaN where unseen or no
        surface), the interpolation error measured and the cells projected exactly.
        Map → ground → image on a lattice of exact projections per strip of map rows,
        interpolated within ``tolerance``, the strips on every core
        (:func:`demtool.mapproject.lattice.points_image_coordinates`).
    """
    from demtool.mapproject.lattice import TOLERANCE_PX, points_image_coordinates

    return points_image_coordinates(sensor, crs, transform, rows, cols, heights,
                                    tolerance=TOLERANCE_PX if tolerance is None else tolerance,
                                    origins=origins)
