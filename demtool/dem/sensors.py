"""Triangulation through sensor models and DEMs on the body's map.

Shared by every calibrated route (frame stereo from a calibrated ``rectify.npz``, and
map-projected line-scan stereo): correspondences given as CSM image coordinates of two
:class:`~demtool.sensors.base.SensorModel` s are intersected in the body-fixed frame
(:func:`triangulate_sensors`), rays that miss each other by too much are dropped
(:func:`default_max_ray_gap`), and the points are gridded on a map projection of the
body (:func:`dem_on_map`): heights in metres above the body's reference sphere
(:attr:`demtool.maps.Body.radius`), measured radially.

Gridding (a robust binning): each map cell gets the median height (and median ray gap) of the points
whose map position falls in it (nearest cell, :func:`demtool.dem.grid.splat_median`);
empty cells inside the stereo overlap — cells whose centre, at the DEM's median
height, is seen by both cameras — are filled by D'Errico's spring metaphor
(:func:`demtool.imaging.interpolate.inpaint_springs`) and flagged in ``filled``; cells outside
stay NaN.  At the default GSD (the images' own) about one point falls in each cell.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from demtool.dem.grid import splat_median
from demtool.errors import ProcessingError
from demtool.logs import get_logger
from demtool.sensors.base import SensorModel

log = get_logger(__name__)

# Default gap limit: median gap + max(GAP_NMADS * NMAD, GAP_GSDS * GSD).
GAP_NMADS = 4.0
GAP_GSDS = 2.0


class Triangulation(NamedTuple):
    """Midpoints of closest approach of two bundles of rays.

    xyz : (N, 3) float64, metres, body-fixed; NaN where the rays are parallel
    gap : (N,) float64, metres, distance between the rays at closest approach
    in_front : (N,) bool, the closest points lie in front of both cameras
    range_left, range_right : (N,) float64, metres along each ray to its closest point
    """

    xyz: np.ndarray
    gap: np.ndarray
    in_front: np.ndarray
    range_left: np.ndarray
    range_right: np.ndarray


def intersect_rays(origin_a, direction_a, origin_b, direction_b) -> Triangulation:
    """Midpoint of the shortest segment between two rays (per row).

    Solves for s, t minimising ``|(a + s u) − (b + t v)|`` (unit u, v):
    ``s = (β e − d) / (1 − β²)``, ``t = (e − β d) / (1 − β²)`` with ``β = u·v``,
    ``d = u·(a − b)``, ``e = v·(a − b)`` (Hartley & Zisserman 2003, §12.2, midpoint
    method).

    origin_*, direction_* : (N, 3) float, metres and unit vectors
    """
    a = np.asarray(origin_a, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(origin_b, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(direction_a, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(direction_b, dtype=np.float64).reshape(-1, 3)
    w = a - b
    beta = np.einsum("ij,ij->i", u, v)
    d = np.einsum("ij,ij->i", u, w)
    e = np.einsum("ij,ij->i", v, w)
    denom = 1.0 - beta * beta
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-14, (beta * e - d) / denom, np.nan)
        t = np.where(denom > 1e-14, (e - beta * d) / denom, np.nan)
    pa = a + s[:, None] * u
    pb = b + t[:, None] * v
    gap = np.linalg.norm(pa - pb, axis=1)
    return Triangulation(0.5 * (pa + pb), gap, (s > 0) & (t > 0), s, t)


def triangulate_sensors(left: SensorModel, right: SensorModel, left_line, left_sample,
                        right_line, right_sample) -> Triangulation:
    """Triangulate correspondences through two sensor models.

    Parameters
    ----------
    left, right : SensorModel
        Any two models in one body-fixed frame (frame or line scan).
    left_line, left_sample, right_line, right_sample : (N,) float
        CSM image coordinates (first pixel centre at 0.5, 0.5) of the same ground points.

    Returns
    -------
    Triangulation
        Rays from each model's ``image_to_ray``; ``in_front`` False where the closest
        points lie behind either camera (reject those).  Computed in batches on every
        core (:func:`demtool.mapproject.threads.batched`), the same values as one batch.
    """
    from demtool.mapproject.threads import batched

    def triangulate(l_line, l_sample, r_line, r_sample):
        ray_l = left.image_to_ray(l_line, l_sample)
        ray_r = right.image_to_ray(r_line, r_sample)
        return intersect_rays(ray_l.origin, ray_l.direction, ray_r.origin, ray_r.direction)

    # each correspondence on its own: in batches on every core, the values of one call
    return Triangulation(*batched(triangulate, *(np.asarray(v, float).ravel() for v in (
        left_line, left_sample, right_line, right_sample))))


def triangulate_ground_rays(origin_left, ground_left, origin_right, ground_right
                            ) -> Triangulation:
    """Triangulate rays given by their origin and a ground point each passes through.

    The map-projected route knows, for each side, the point on the surface its
    orthoimage was projected on and the raw pixel that sees it (the ray of that pixel
    passes through the point, to the projection's precision), so a ray is its origin
    (``image_to_ray``'s at the pixel) and the direction to the point: the same ray as
    ``image_to_ray`` gives, without interpolating the sensor's attitude at every point.

    Parameters
    ----------
    origin_left, ground_left, origin_right, ground_right : (N, 3) float
        Body-fixed metres.

    Returns
    -------
    Triangulation
        As :func:`triangulate_sensors`, in batches on every core (the values of one
        batch).
    """
    from demtool.mapproject.threads import batched

    def triangulate(o_l, g_l, o_r, g_r):
        with np.errstate(invalid="ignore", divide="ignore"):
            u = g_l - o_l
            u /= np.linalg.norm(u, axis=1)[:, None]
            v = g_r - o_r
            v /= np.linalg.norm(v, axis=1)[:, None]
        return intersect_rays(o_l, u, o_r, v)

    return Triangulation(*batched(triangulate, *(np.asarray(a, dtype=np.float64).reshape(
        -1, 3) for a in (origin_left, ground_left, origin_right, ground_right))))


#: the largest fraction of the points in front of both cameras a user's --max-ray-gap may
#: drop: beyond it the DEM is interpolated from a tenth of its measurements or less (the
#: default threshold, median + max(4 NMAD, 2 GSD), drops less than half by construction)
MAX_DROPPED_FRACTION = 0.9


def screen_ray_gaps(gap: np.ndarray, in_front: np.ndarray, max_ray_gap: float | None,
                    gsd_m: float) -> tuple[np.ndarray, float, float]:
    """Which triangulated points to keep: in front of both cameras and with rays that
    miss each other by at most ``max_ray_gap`` (default :func:`default_max_ray_gap`).

    Parameters
    ----------
    gap : (N,) float64
        Gap between the two rays of each point, metres.
    in_front : (N,) bool
        Points in front of both cameras (and finite).
    max_ray_gap : float or None
        The user's ``--max-ray-gap``, metres.
    gsd_m : float
        Ground sample distance, metres.

    Returns
    -------
    keep : (N,) bool
    max_gap, median_gap : float
        The threshold used and the median gap of the points in front, metres.

    A threshold that drops most points is logged as a warning (issue 31); a
    ``--max-ray-gap`` that drops more than :data:`MAX_DROPPED_FRACTION` of them is refused
    (issue 46: 98.8 % dropped gave a DEM interpolated almost everywhere, exit 0).

    Raises
    ------
    ParameterError
        ``--max-ray-gap`` keeps less than ``1 − MAX_DROPPED_FRACTION`` of the points.
    """
    from demtool.errors import ParameterError

    gaps = gap[in_front]
    median_gap = float(np.median(gaps))  # once: the default threshold starts from it too
    max_gap = (float(max_ray_gap) if max_ray_gap is not None
               else default_max_ray_gap(gaps, gsd_m, median=median_gap))
    keep = in_front & (gap <= max_gap)
    dropped, front = int((in_front & ~keep).sum()), int(in_front.sum())
    if max_ray_gap is not None and dropped > MAX_DROPPED_FRACTION * front:
        raise ParameterError(
            f"--max-ray-gap {max_gap:.3g} m drops {dropped} of {front} points "
            f"({100.0 * dropped / front:.1f} %; median gap {median_gap:.3g} m): the DEM "
            f"would be interpolated from the {front - dropped} left (at most "
            f"{100 * MAX_DROPPED_FRACTION:.0f} % may be dropped); give a larger --max-ray-gap "
            "or leave it out (median + max(4 NMAD, 2 GSD))")
    if dropped > 0.5 * front:
        log.warning("--max-ray-gap %.3g m drops %d of %d points (%.1f %%): the models may not "
                    "fit this disparity (or give a larger --max-ray-gap)", max_gap, dropped,
                    front, 100.0 * dropped / max(1, front))
    return keep, max_gap, median_gap


def default_max_ray_gap(gap: np.ndarray, gsd_m: float, *,
                        median: float | None = None) -> float:
    """The default ``--max-ray-gap``: ``median + max(4 NMAD, 2 GSD)`` of the gaps, metres.

    Relative to the pair's median gap, so that a systematic offset of the two cameras
    (unadjusted SPICE: every ray pair misses by about the same distance) is reported,
    not used to reject the whole pair; only rays that miss by much more than their
    neighbours (mismatches) are rejected.  ``median``: ``np.median(gap)`` when the caller
    has it (used where every gap is finite: then it is the median of the finite ones).
    """
    g = np.asarray(gap, dtype=np.float64)
    finite = np.isfinite(g)
    if not finite.all():
        g, median = g[finite], None  # a given median was of all the gaps
    if g.size == 0:
        return float("inf")
    if median is None:
        median = float(np.median(g))
    nmad = 1.4826 * float(np.median(np.abs(g - median)))
    return median + max(GAP_NMADS * nmad, GAP_GSDS * float(gsd_m))


def overlap_mask(grid, left: SensorModel, right: SensorModel, height: float) -> np.ndarray:
    """Cells of ``grid`` whose centre, ``height`` metres above the sphere, both cameras see.

    Most cells are decided on a lattice of exact projections, the cells near an image edge
    one by one (:func:`demtool.dem.overlap.cells_seen`: the same answer as projecting every
    cell).

    Returns (rows, columns) bool.
    """
    from demtool.dem.overlap import cells_seen
    from demtool.mapproject.threads import available_threads, ordered_map

    seen = list(ordered_map(lambda model: cells_seen(model, grid, float(height)),
                            (left, right), threads=min(2, available_threads())))
    return seen[0] & seen[1]


class MapDem(NamedTuple):
    """A DEM on the body's map.

    dem : (rows, columns) float32, metres above the reference sphere, NaN = no data
    error : (rows, columns) float32, median ray gap of the cell's points, metres
        (NaN where filled or empty)
    filled : (rows, columns) bool, cells filled by interpolation
    overlap : (rows, columns) bool, the stereo overlap
    grid : demtool.maps.MapGrid (CRS and transform)
    report : dict of summary figures
    points : (N, 3) float64, the gridded points: map x, y (metres, ``grid.crs``) and
        height above the reference sphere (metres)
    point_gaps : (N,) float64, their ray gaps, metres
    point_index : (N,) int, each point's index in the ``xyz`` given to :func:`dem_on_map`
    """

    dem: np.ndarray
    error: np.ndarray
    filled: np.ndarray
    overlap: np.ndarray
    grid: Any
    report: dict
    points: np.ndarray | None = None
    point_gaps: np.ndarray | None = None
    point_index: np.ndarray | None = None


class MapPoints(NamedTuple):
    """Body-fixed points placed on a map.

    grid : demtool.maps.MapGrid, the smallest grid of the GSD covering the points
    x, y : (N,) float64, metres, map coordinates in ``grid.crs``
    height : (N,) float64, metres above the body's reference surface
    """

    grid: Any
    x: np.ndarray
    y: np.ndarray
    height: np.ndarray


def points_on_map(xyz: np.ndarray, body, *, gsd_m: float, projection: str = "auto",
                  crs: Any = None) -> MapPoints:
    """Map coordinates and heights of finite body-fixed points, and the grid covering
    them: :func:`demtool.maps.grids.grid_from_xyz`'s grid with the points' longitude,
    latitude, height and map x, y computed once, in batches on every core (the values
    of one call).

    xyz : (N, 3) float, metres, body-fixed, finite; body, gsd_m, projection, crs as in
    :func:`dem_on_map`.
    """
    from demtool.dem.map_parts import finite_extent
    from demtool.mapproject.threads import batched
    from demtool.maps.frames import xyz_to_lonlat_height
    from demtool.maps.grids import snap_grid
    from demtool.maps.projections import choose_projection, lonlat_to_map

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    lon, lat, height = batched(lambda p: xyz_to_lonlat_height(p, radii=body.surface), xyz)
    if crs is None:
        crs = choose_projection(body, lon, lat, projection)
    x, y = batched(lambda a, b: lonlat_to_map(crs, a, b), lon, lat)
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    extent = finite_extent(x, y)  # of the points with a finite x and y
    if extent is None:
        raise ValueError("footprint cannot be projected in the chosen CRS")
    grid = snap_grid(crs, *extent, gsd_m)
    if grid.crs != crs:  # the grid's own CRS object places the points, as dem_on_map did
        x, y = batched(lambda a, b: lonlat_to_map(grid.crs, a, b), lon, lat)
    return MapPoints(grid, np.asarray(x), np.asarray(y), height)


def dem_on_map(xyz: np.ndarray, gap: np.ndarray, body, *, gsd_m: float,
               projection: str = "auto", crs: Any = None,
               left: SensorModel | None = None, right: SensorModel | None = None,
               fill: bool = True, median_px: int = 0,
               placed: MapPoints | None = None) -> MapDem:
    """Grid triangulated points as heights above the body's sphere on a map.

    Parameters
    ----------
    xyz : (N, 3) float, metres, body-fixed (the points kept after the gap test)
    gap : (N,) float, metres, their ray gaps
    body : demtool.maps.Body
    gsd_m : float, pixel size of the map, metres
    projection : {"auto", "equirectangular", "polar-stereographic"}
    crs : CRS-like, optional, a given projected CRS instead
    left, right : SensorModel, optional
        The pair; with them the empty cells inside the stereo overlap are filled
        (``fill``), otherwise the cells inside the points' extent.
    fill : bool
        Fill gaps (spring metaphor) inside the overlap.
    median_px : int
        Median filter after filling (0 = off; odd), :func:`demtool.dem.grid.fill_and_smooth`.
    placed : MapPoints, optional
        :func:`points_on_map` of these ``xyz`` (with the same body, GSD, projection and
        CRS), when the caller has it already.

    Returns
    -------
    MapDem
    """
    from demtool.dem.grid import fill_and_smooth
    from demtool.dem.map_parts import finish_grid, finite_points, map_pixels, point_columns
    from demtool.mapproject.threads import available_threads, ordered_map

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    gap = np.asarray(gap, dtype=np.float64).ravel()
    keep = finite_points(xyz)
    if not keep.all():
        xyz, gap = xyz[keep], gap[keep]
    if len(xyz) < 3:
        raise ProcessingError(f"only {len(xyz)} triangulated points: nothing to grid")
    index = np.flatnonzero(keep) if len(xyz) < len(keep) else np.arange(len(keep))
    if placed is None or placed.x.size != len(xyz):
        placed = points_on_map(xyz, body, gsd_m=gsd_m, projection=projection, crs=crs)
    grid, x, y, height = placed
    # north-up: col = (x − c) / a, row = (y − f) / e; pixel centres at integers
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    pixels = map_pixels(x, y, grid.transform)
    # Two threads, each a chain of independent work (2048² map: about 2 CPU s each): the
    # heights' medians then the gap fill, which needs them and runs on one core (scipy's
    # sparse solve); beside them the stereo overlap (the two cameras one after the
    # other) then the gaps' medians.  Before, the two medians ran side by side, then the
    # fill beside the overlap, whose two threads were done long before the fill.
    def heights_then_fill():
        dem, counts = splat_median(pixels, height, grid.shape)
        full = (fill_and_smooth(dem, median_px=median_px).dem
                if fill and np.isfinite(dem).any() else None)
        return dem, counts, full

    def overlap_then_gaps():
        median_height = float(np.median(height))
        if left is not None and right is not None:
            # on this thread alone (ordered_map gives each call one numba thread)
            overlap = overlap_mask(grid, left, right, median_height)
        else:
            overlap = np.ones(grid.shape, dtype=bool)
        error, _ = splat_median(pixels, gap, grid.shape)
        return median_height, overlap, error

    (dem, counts, full), (median_height, overlap, error) = ordered_map(
        lambda task: task(), (heights_then_fill, overlap_then_gaps),
        threads=min(2, available_threads()))
    done = finish_grid(dem, error, counts, overlap, full, median_px)
    report = {
        "map_shape": list(grid.shape),
        "map_gsd_m": float(gsd_m),
        "overlap_cells": done.overlap_cells,
        "measured_cells": done.measured_cells,
        "filled_cells": done.filled_cells,
        "measured_fraction_of_overlap": float(done.measured_cells
                                              / max(1, done.overlap_cells)),
        "points_per_measured_cell": done.points_per_measured_cell,
        "height_min_m": done.height_min,
        "height_max_m": done.height_max,
        "height_median_m": median_height,
    }
    return MapDem(done.dem, done.error, done.filled, overlap, grid, report,
                  points=point_columns(x, y, height), point_gaps=gap,
                  point_index=index)
