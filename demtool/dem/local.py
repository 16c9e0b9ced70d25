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
                      median_px: int = 0) -> LocalDem:
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
