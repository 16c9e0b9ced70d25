"""DEMs in a local metric frame, from two calibrated cameras that have no body.

Rovers, landers, lab rigs and drones carry calibrated cameras (ASP ``.tsai``,
``cameras.npz``, OpenCV/COLMAP pinholes) whose models live in a local frame — metres,
but no planet, no map projection.  Their correspondences are triangulated in that frame
(:func:`demtool.dem.sensors.triangulate_sensors`: points behind either camera and rays
that miss each other by much more than their neighbours are dropped, as on the body's
map) and gridded here as **heights along a stated up axis on a local metric grid**:

* the up axis is the frame's own +Z, or a given direction (``--up``: gravity reversed,
  e.g. ``0,0,-1`` for a rover frame whose Z points down);
* the grid's axes (:func:`local_frame`): x = the frame's X axis projected on the plane
  normal to up (its Y axis when X is along up), y = up × x; a right-handed (x, y, up)
  triad; heights are ``p · up`` in metres (zero at the frame's origin);
* the raster is "north-up" in these axes: row 0 at the largest y,
  ``Affine(gsd, 0, x_min, 0, −gsd, y_max)``, and claims no CRS.

Gridding is the map route's (:func:`demtool.dem.sensors.dem_on_map`): each cell gets the
median height of the points falling in it (:func:`demtool.dem.grid.splat_median`), after
the local-median outlier test of the image-frame routes (Westerweel & Scarano 2005,
:func:`demtool.dem.grid.local_median_inliers`); empty cells are filled by the spring
metaphor (:func:`demtool.imaging.interpolate.inpaint_springs`) where the filled point is seen by
both cameras, in front of them, and stay NaN elsewhere.  This is what ASP's
``point2dem`` does with a point cloud in a local (non-geodetic) frame (``--t_srs`` of a
local projection), here without the intermediate cloud unless asked for
(:func:`demtool.io.write_ply`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from demtool.dem.grid import local_median_inliers, splat_median
from demtool.errors import ProcessingError
from demtool.sensors.base import SensorModel

#: points outside these percentiles of each horizontal axis are left off the grid (a few
#: mismatches at infinity must not stretch the grid over kilometres)
EXTENT_PERCENTILES = (0.5, 99.5)
#: the grid covers the points within this many times their median range of the left
#: camera (with ``center``): the bulk of a perspective view, where the GSD defaulted from
#: the median range's pixel footprint means something
BULK_RANGE_FACTOR = 3.0
#: a filled cell is hidden when it lies this many cells plus this fraction of its range
#: behind the surface a camera saw along its pixel
OCCLUSION_CELLS = 3.0
OCCLUSION_RANGE = 0.02
#: largest grid the route builds (cells); more is refused with the fix (--gsd)
MAX_CELLS = 60_000_000


class LocalFrame(NamedTuple):
    """Axes of a local DEM in the models' frame.

    axes : (3, 3) float64, rows x, y, up (unit, right-handed)
    """

    axes: np.ndarray

    @property
    def up(self) -> np.ndarray:
        return self.axes[2]

    def to_local(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) points of the models' frame → (N, 3) (x, y, height) metres."""
        return np.asarray(xyz, dtype=np.float64).reshape(-1, 3) @ self.axes.T

    def to_frame(self, local: np.ndarray) -> np.ndarray:
        """(N, 3) (x, y, height) → points of the models' frame."""
        return np.asarray(local, dtype=np.float64).reshape(-1, 3) @ self.axes

    def tags(self) -> dict[str, str]:
        """Raster tags stating the frame (no CRS is claimed)."""
        def text(v):
            return ",".join(f"{float(c):.9g}" for c in v)
        return {"local_x_axis": text(self.axes[0]), "local_y_axis": text(self.axes[1]),
                "local_up": text(self.axes[2]),
                "height_reference": "metres along local_up from the models' frame origin"}


def local_frame(up=None) -> LocalFrame:
    """The grid axes for an up direction (default the frame's +Z).

    Parameters
    ----------
    up : (3,) float, optional
        Up direction in the models' frame (any length but zero).

    Returns
    -------
    LocalFrame
        x = the frame's X projected normal to up (Y when X is within 1° of up),
        y = up × x, up.
    """
    u = np.asarray((0.0, 0.0, 1.0) if up is None else up, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(u))
    if not (np.isfinite(norm) and norm > 0):
        raise ValueError(f"the up direction {tuple(u)} has no length")
    u = u / norm
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        x = axis - (axis @ u) * u
        if np.linalg.norm(x) > np.sin(np.radians(1.0)):
            break
    x /= np.linalg.norm(x)
    y = np.cross(u, x)
    return LocalFrame(np.stack([x, y, u]))


def footprint_gsd(xyz: np.ndarray, center: np.ndarray, frame: LocalFrame,
                  pixel_angle: float) -> float:
    """Default GSD: the median side of one pixel's footprint on the horizontal plane.

    A pixel at range r covers (r · pixel_angle)² across the ray, stretched by 1 / sin(e)
    on the plane normal to up (e: the ray's elevation angle), so the side of the
    equal-area square is ``r · pixel_angle / √sin e``; the median over the points.

    xyz : (N, 3) points, metres; center : (3,) the camera centre; pixel_angle : radians
    """
    rel = np.asarray(xyz, dtype=np.float64) - np.asarray(center, dtype=np.float64)
    r = np.linalg.norm(rel, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        sin_e = np.clip(np.abs(rel @ frame.up) / r, 0.05, 1.0)
    side = r * pixel_angle / np.sqrt(sin_e)
    side = side[np.isfinite(side) & (side > 0)]
    if side.size == 0:
        raise ProcessingError("no point to estimate the GSD from")
    return float(np.median(side))


#: the ground's fitted normal snaps to a frame axis within this angle (degrees): frames
#: are built with gravity along an axis; a steeper slope keeps the normal itself
SNAP_AXIS_DEG = 15.0
#: points farther than this many times the matches' farthest range (their 99th
#: percentile), or nearer than the nearest over it, are outliers the matches do not imply
MATCH_RANGE_FACTOR = 2.0


def fit_ground_normal(xyz: np.ndarray, centers: np.ndarray, *, iterations: int = 4
                      ) -> tuple[np.ndarray, float]:
    """The normal of the plane fitted to the points, pointing to the cameras' side.

    Total least squares (the smallest principal axis of the points), refitted on the
    points within 3 NMAD of the plane ``iterations`` times.

    Parameters
    ----------
    xyz : (N, 3) float, metres, the models' frame
    centers : (K, 3) float, the camera centres, metres

    Returns
    -------
    normal : (3,) unit vector, (mean centre − plane point) · normal > 0
    rms_m : float, RMS distance of the kept points to the plane, metres
    """
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) > 200_000:
        p = p[np.random.default_rng(0).choice(len(p), 200_000, replace=False)]
    if len(p) < 3:
        raise ProcessingError(f"only {len(p)} points: no ground to fit")
    keep = np.ones(len(p), dtype=bool)
    for _ in range(iterations):
        mean = p[keep].mean(axis=0)
        normal = np.linalg.svd(p[keep] - mean, full_matrices=False)[2][2]
        distance = (p - mean) @ normal
        nmad = 1.4826 * np.median(np.abs(distance - np.median(distance)))
        keep = np.abs(distance - np.median(distance)) <= max(3.0 * nmad, 1e-9)
    side = (np.mean(np.asarray(centers, dtype=np.float64).reshape(-1, 3), axis=0) - mean)
    normal = normal if side @ normal > 0 else -normal
    return normal, float(np.sqrt(np.mean(distance[keep] ** 2)))


def infer_up(xyz: np.ndarray, centers: np.ndarray) -> tuple[np.ndarray, str]:
    """The up direction of points seen by cameras standing above them.

    The ground's fitted normal on the cameras' side (:func:`fit_ground_normal`); the
    frame axis (±X, ±Y, ±Z) nearest it when within :data:`SNAP_AXIS_DEG` (a rover frame
    is built with gravity along an axis: z down in ASP's K10 example).

    Returns
    -------
    up : (3,) unit vector
    source : str, how it was found (for the log and the sidecar)
    """
    normal, _ = fit_ground_normal(xyz, centers)
    axis = np.argmax(np.abs(normal))
    snapped = np.zeros(3)
    snapped[axis] = np.sign(normal[axis])
    angle = float(np.degrees(np.arccos(np.clip(normal @ snapped, -1.0, 1.0))))
    name = ("-" if snapped[axis] < 0 else "+") + "XYZ"[axis]
    if angle <= SNAP_AXIS_DEG:
        return snapped, (f"inferred: the frame's {name} axis, {angle:.1f}° from the normal "
                         "of the ground fitted to the points, on the cameras' side")
    return normal, ("inferred: the normal of the ground fitted to the points, on the "
                    f"cameras' side ({angle:.1f}° from the nearest frame axis {name})")


def check_up(up: np.ndarray, xyz: np.ndarray, centers: np.ndarray, source: str) -> float:
    """Refuse an up direction the cameras do not stand above the ground along.

    Returns the height of the cameras' mean centre above the points' median height
    along ``up`` (metres, positive).

    Raises
    ------
    ProcessingError
        One line naming ``source`` (``--up``): the cameras lie at or below the median of
        the points along it, with the up the geometry gives.
    """
    u = np.asarray(up, dtype=np.float64).reshape(3)
    u = u / np.linalg.norm(u)
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    camera = float(np.mean(np.asarray(centers, dtype=np.float64).reshape(-1, 3), axis=0) @ u)
    above = camera - float(np.median(p @ u))
    if above <= 0:
        inferred, _ = infer_up(p, centers)
        raise ProcessingError(
            f"{source} {','.join(f'{v:g}' for v in u)} puts the cameras {-above:.3g} m "
            "below the ground they look at (the median of the points along it): that is "
            "down; the geometry gives up ≈ " + ",".join(f"{v:.3g}" for v in inferred)
            + " (leave --up out to use it)")
    return above


#: rays that converge by less than this many pixels of the rectified focal length leave
#: the range unknown to more than 1 / this per pixel of disparity: dropped (the ground
#: seen along the baseline, at the edge of a fish-eye)
MIN_CONVERGENCE_PX = 5.0


def weak_convergence(xyz: np.ndarray, centers: np.ndarray, f_px: float,
                     min_px: float = MIN_CONVERGENCE_PX) -> np.ndarray:
    """(N,) bool: points whose two rays meet at less than ``min_px / f_px`` radians.

    Near the epipoles (the ground along the baseline) the rays are almost parallel: one
    pixel of disparity moves the point by ``1 / (f γ)`` of its range (γ the rays'
    angle), and mismatches there land metres away.  ASP's ``stereo`` has the same
    guard (``--min-triangulation-angle``).
    """
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(centers, dtype=np.float64).reshape(2, 3)
    a = p - c[0]
    b = p - c[1]
    cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    with np.errstate(invalid="ignore"):
        return np.arccos(np.clip(cos, -1.0, 1.0)) * float(f_px) < min_px


#: images whose "up" (towards the first line) points more than 120° from up are upside
#: down in the frame (cos 120° = −0.5)
UPRIGHT_COS = -0.5


def image_up(model: SensorModel) -> np.ndarray:
    """Unit direction, in the models' frame, of the image's up (towards line 0) at its
    centre: the ray one line above minus the centre's ray."""
    line, sample = 0.5 * model.lines, 0.5 * model.samples
    rays = model.image_to_ray(np.array([line, line - 1.0]), np.array([sample, sample]))
    step = np.asarray(rays.direction[1] - rays.direction[0], dtype=np.float64)
    return step / np.linalg.norm(step)


def check_upright(up: np.ndarray, models: tuple[SensorModel, ...], source: str) -> float:
    """Refuse an up along which the cameras' images stand upside down.

    A camera looks at the ground with its images upright (their top towards the sky); a
    model whose rotation is transposed or inverted still triangulates the matches, into
    a mirrored scene in front of the cameras, often below them, where the fitted ground
    and the cameras' side agree: the images' up is what betrays it.

    Returns the cosine between up and the cameras' mean image up.

    Raises
    ------
    ProcessingError
        One line naming ``source`` and the angle.
    """
    u = np.asarray(up, dtype=np.float64).reshape(3)
    u = u / np.linalg.norm(u)
    mean = np.mean([image_up(m) for m in models], axis=0)
    cos = float(mean @ u / max(np.linalg.norm(mean), 1e-12))
    if cos < UPRIGHT_COS:
        raise ProcessingError(
            f"{source}: the cameras' images would stand upside down along up "
            f"{','.join(f'{v:.3g}' for v in u)} (their top {np.degrees(np.arccos(cos)):.0f}° "
            "from it): the models' rotations may be transposed or inverted (a .tsai's R "
            "is camera-to-world); check them, or rotate the image axes of a camera mounted "
            "upside down")
    return cos


def beyond_matches(xyz: np.ndarray, center: np.ndarray, match_ranges: np.ndarray,
                   factor: float = MATCH_RANGE_FACTOR) -> np.ndarray:
    """(N,) bool: points whose range from ``center`` lies far outside the matches' ranges.

    The matches (rectify's control points, triangulated) bound the scene the pair sees:
    a dense disparity beyond ``factor`` times their 99th percentile of range (or nearer
    than their 1st over ``factor``) is a mismatch (sky, sgm's range widened onto noise),
    not terrain.
    """
    r = np.linalg.norm(np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
                       - np.asarray(center, dtype=np.float64), axis=1)
    m = np.asarray(match_ranges, dtype=np.float64)
    m = m[np.isfinite(m) & (m > 0)]
    if m.size < 3:
        return np.zeros(len(r), dtype=bool)
    near, far = np.percentile(m, [1.0, 99.0])
    with np.errstate(invalid="ignore"):
        return (r > factor * far) | (r < near / factor)


class LocalDem(NamedTuple):
    """A DEM on a local metric grid.

    dem : (rows, columns) float32, metres along ``frame.up``, NaN = no data
    error : (rows, columns) float32, median ray gap of the cell's points, metres
    filled : (rows, columns) bool, cells filled by interpolation
    transform : affine.Affine, grid (x, y) metres of the local axes
    frame : LocalFrame
    report : dict of summary figures
    """

    dem: np.ndarray
    error: np.ndarray
    filled: np.ndarray
    transform: Any
    frame: LocalFrame
    report: dict


def _seen_by_both(points: np.ndarray, models: tuple[SensorModel, ...]) -> np.ndarray:
    """(N,) bool: each point projects inside every model's image, in front of it."""
    from demtool.dem.overlap import inside_image

    seen = np.isfinite(points).all(axis=1)
    for model in models:
        seen &= inside_image(model, *model.ground_to_image(points))
        center = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64)
        look = np.asarray(model.look_direction(0.5 * model.lines, 0.5 * model.samples),
                          dtype=np.float64).reshape(3)
        seen &= (points - center) @ look > 0
    return seen


def range_buffer(model: SensorModel, xyz: np.ndarray) -> np.ndarray:
    """Nearest range (m) of the points in each pixel of ``model`` (a z-buffer), NaN where
    no point falls; each pixel also takes its 3 × 3 neighbours' minimum (the points are
    one per disparity, not one per pixel of this image)."""
    from scipy.ndimage import minimum_filter

    points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    line, sample = model.ground_to_image(points)
    center = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64)
    ranges = np.linalg.norm(points - center, axis=1)
    row, col = np.floor(line), np.floor(sample)
    ok = (np.isfinite(row) & np.isfinite(col) & (row >= 0) & (col >= 0)
          & (row < model.lines) & (col < model.samples))
    buffer = np.full((model.lines, model.samples), np.inf)
    np.minimum.at(buffer, (row[ok].astype(np.int64), col[ok].astype(np.int64)), ranges[ok])
    buffer = minimum_filter(buffer, size=3, mode="nearest")
    buffer[~np.isfinite(buffer)] = np.nan
    return buffer


def hidden(points: np.ndarray, model: SensorModel, buffer: np.ndarray,
           tolerance_m: np.ndarray | float) -> np.ndarray:
    """(N,) bool: points lying more than ``tolerance_m`` behind the nearest surface the
    camera saw along their pixel (``buffer`` from :func:`range_buffer`): occluded."""
    line, sample = model.ground_to_image(points)
    row, col = np.floor(line), np.floor(sample)
    ok = (np.isfinite(row) & np.isfinite(col) & (row >= 0) & (col >= 0)
          & (row < model.lines) & (col < model.samples))
    seen_range = np.full(len(points), np.nan)
    seen_range[ok] = buffer[row[ok].astype(np.int64), col[ok].astype(np.int64)]
    center = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64)
    ranges = np.linalg.norm(points - center, axis=1)
    with np.errstate(invalid="ignore"):
        return ranges > seen_range + tolerance_m


def dem_on_local_grid(xyz: np.ndarray, gap: np.ndarray, frame: LocalFrame, *,
                      gsd_m: float, left: SensorModel | None = None,
                      right: SensorModel | None = None, neighbours: int = 16,
                      threshold: float = 3.0, fill: bool = True,
                      median_px: int = 0, center: np.ndarray | None = None) -> LocalDem:
    """Grid triangulated points as heights along ``frame.up`` on a local metric grid.

    Parameters
    ----------
    xyz : (N, 3) float, metres, the models' frame (points kept by the cheirality and gap
        tests)
    gap : (N,) float, metres, their ray gaps
    frame : LocalFrame
    gsd_m : float, cell size, metres
    left, right : SensorModel, optional
        The pair: filled cells must be seen by both (in front, inside the images, not
        hidden behind the surface the points show, :func:`hidden`) at their filled
        height; without them every cell inside the points' extent is filled.
    neighbours, threshold : the local-median outlier test (threshold ≤ 0: off)
    fill : bool, fill the gaps
    median_px : int, median filter after filling (0 = off; odd)
    center : (3,) float, optional
        The left camera's centre: the grid then covers the bulk of the points, those
        within :data:`BULK_RANGE_FACTOR` times their median range of it (a perspective
        view's far ground spreads a few per cent of the points over most of the area:
        K10's 2 % beyond 27 m would stretch a 5 mm grid over 25 m); the others are left
        off the grid and counted (``points_beyond_bulk``).

    Returns
    -------
    LocalDem

    Raises
    ------
    ProcessingError
        Fewer than 3 points, or a grid larger than :data:`MAX_CELLS`.
    """
    from affine import Affine

    from demtool.dem.grid import fill_and_smooth

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    gap = np.asarray(gap, dtype=np.float64).ravel()
    keep = np.isfinite(xyz).all(axis=1)
    beyond_bulk = 0
    if center is not None and keep.any():
        ranges = np.linalg.norm(xyz - np.asarray(center, dtype=np.float64), axis=1)
        far = keep & (ranges > BULK_RANGE_FACTOR * np.median(ranges[keep]))
        beyond_bulk = int(far.sum())
        keep &= ~far
    local, gap = frame.to_local(xyz[keep]), gap[keep]
    if len(local) < 3:
        raise ProcessingError(f"only {len(local)} triangulated points: nothing to grid")
    lo = np.percentile(local[:, :2], EXTENT_PERCENTILES[0], axis=0)
    hi = np.percentile(local[:, :2], EXTENT_PERCENTILES[1], axis=0)
    inside = ((local[:, :2] >= lo) & (local[:, :2] <= hi)).all(axis=1)
    outside_extent = int((~inside).sum())
    local, gap = local[inside], gap[inside]
    x0 = np.floor(lo[0] / gsd_m) * gsd_m
    y1 = np.ceil(hi[1] / gsd_m) * gsd_m
    width = int(np.ceil((hi[0] - x0) / gsd_m)) + 1
    height = int(np.ceil((y1 - lo[1]) / gsd_m)) + 1
    if width * height > MAX_CELLS:
        raise ProcessingError(f"the points span {hi[0] - lo[0]:.4g} × {hi[1] - lo[1]:.4g} m: "
                              f"a {width} × {height} grid at {gsd_m:.4g} m; give a coarser "
                              "--gsd")
    transform = Affine(gsd_m, 0.0, x0, 0.0, -gsd_m, y1)
    cols = (local[:, 0] - x0) / gsd_m - 0.5
    rows = (y1 - local[:, 1]) / gsd_m - 0.5
    pixels = np.stack([cols, rows], axis=-1)
    heights = local[:, 2]
    inliers = np.ones(len(heights), dtype=bool)
    if threshold > 0 and len(heights) > neighbours:
        inliers = local_median_inliers(pixels, heights, neighbours=neighbours,
                                       threshold=threshold)
    dem, counts = splat_median(pixels[inliers], heights[inliers], (height, width))
    error, _ = splat_median(pixels[inliers], gap[inliers], (height, width))
    measured = np.isfinite(dem)
    filled = np.zeros(dem.shape, dtype=bool)
    out = dem.copy()
    if fill and measured.any():
        full = fill_and_smooth(dem, median_px=median_px).dem
        candidates = ~measured
        if left is not None and right is not None:
            rr, cc = np.nonzero(candidates)
            points = frame.to_frame(np.stack([x0 + (cc + 0.5) * gsd_m,
                                              y1 - (rr + 0.5) * gsd_m, full[rr, cc]], axis=-1))
            seen = _seen_by_both(points, (left, right))
            kept = frame.to_frame(local[inliers])
            for model in (left, right):  # occluded: behind what this camera saw
                center = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64)
                tolerance = OCCLUSION_CELLS * gsd_m + OCCLUSION_RANGE * np.linalg.norm(
                    points - center, axis=1)
                seen &= ~hidden(points, model, range_buffer(model, kept), tolerance)
            candidates[rr[~seen], cc[~seen]] = False
        filled = candidates
        out = np.where(filled | (measured & (median_px > 1)), full, dem)
    out[~(measured | filled)] = np.nan
    report = {
        "grid_shape": [height, width],
        "grid_gsd_m": float(gsd_m),
        "points_outside_extent": outside_extent,
        "points_beyond_bulk": beyond_bulk,
        "outliers_removed": int((~inliers).sum()),
        "measured_cells": int(measured.sum()),
        "filled_cells": int(filled.sum()),
        "points_per_measured_cell": float(counts[measured].mean()) if measured.any() else 0.0,
        "height_min_m": float(np.nanmin(out)),
        "height_max_m": float(np.nanmax(out)),
        "height_median_m": float(np.median(heights[inliers])),
    }
    return LocalDem(out.astype(np.float32), error.astype(np.float32), filled, transform,
                    frame, report)


def cells_behind_cameras(dem: np.ndarray, transform, frame: LocalFrame,
                         models: tuple[SensorModel, ...]) -> int:
    """Number of valid cells whose point lies behind (or beside) any camera's image plane.

    The check of the issue's acceptance test: every cell of a local DEM is a point in front
    of both cameras.
    """
    rr, cc = np.nonzero(np.isfinite(dem))
    x = transform.c + (cc + 0.5) * transform.a
    y = transform.f + (rr + 0.5) * transform.e
    points = frame.to_frame(np.stack([x, y, dem[rr, cc]], axis=-1))
    behind = np.zeros(len(points), dtype=bool)
    for model in models:
        center = np.asarray(model.camera_center(0.5 * model.lines), dtype=np.float64)
        look = np.asarray(model.look_direction(0.5 * model.lines, 0.5 * model.samples),
                          dtype=np.float64).reshape(3)
        behind |= (points - center) @ look <= 0
    return int(behind.sum())
