"""DEM from bundle-adjusted sparse points (the BAM route of the Rosetta NavCam study).

The points are projected into the target camera; their depths become heights
(positive toward the camera) either by eq. 2 of the study, when the model has an
arbitrary scale, or directly in metres when the bundle was aligned to known cameras.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from demtool.bundle import project_points
from demtool.errors import ProcessingError
from demtool.sensors.base import SensorModel
from demtool.sensors.pinhole import PinholeCamera


@dataclass(frozen=True)
class TargetSamples:
    """Height samples in the target image.

    Attributes
    ----------
    pixels : (N, 2) float64
        Positions (x, y) in the target image, pixels.
    heights : (N,) float64
        Heights, metres, positive toward the camera.
    depth : (N,) float64
        Camera z of each point, model units (metres when aligned).
    index : (N,) int64
        Index of each sample's point in the input point array.
    """

    pixels: np.ndarray
    heights: np.ndarray
    depth: np.ndarray
    index: np.ndarray


def project_to_target(points: np.ndarray, camera: PinholeCamera,
                      distortion: Sequence[float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray,
                                                                          np.ndarray]:
    """Project points into the target camera and keep those that land in the image.

    Parameters
    ----------
    points : (N, 3) float
        Model (or world) coordinates.
    camera : PinholeCamera
        The target camera.
    distortion : (2,) float
        Radial distortion (k1, k2) of the camera (``bundle.npz`` key ``distortion``).

    Returns
    -------
    pixels : (M, 2) float64
    depth : (M,) float64
    index : (M,) int64
        Indices of the kept points.

    Raises
    ------
    ProcessingError
        If no point is in front of the camera and inside the image.
    """
    pixels, depth = project_points(camera, points, distortion)
    inside = (np.isfinite(pixels).all(axis=1) & (depth > 0)
              & (pixels[:, 0] > -0.5) & (pixels[:, 0] < camera.width - 0.5)
              & (pixels[:, 1] > -0.5) & (pixels[:, 1] < camera.height - 0.5))
    if not inside.any():
        raise ProcessingError(f"none of the {len(points)} points projects into the target "
                              f"image ({camera.width}×{camera.height} px)")
    index = np.flatnonzero(inside)
    return pixels[index], depth[index], index


def heights_from_relative_depth(depth: np.ndarray, distance_m: float, *,
                                mean_depth: float | None = None) -> np.ndarray:
    """Metric heights from the depths of a model of arbitrary scale (NavCam study, eq. 2).

    The depth offset of a point from the mean depth, in metres, is
    ``(z / mean(z) - 1) * d`` with d the spacecraft–surface distance; the height
    (positive toward the camera) is its negative.  ``mean_depth`` gives mean(z) when
    it is not these points' own mean (dense points converted with the tie points'
    mean, :mod:`demtool.dem.dense`, so that both share one datum and scale).

    Parameters
    ----------
    depth : (N,) float
        Camera z of the points in the target camera, model units (any scale).
    distance_m : float
        Spacecraft–surface distance d, metres.
    mean_depth : float, optional
        The reference depth mean(z), model units (default: the mean of ``depth``).

    Returns
    -------
    (N,) float64
        Heights, metres, positive toward the camera, zero at the mean depth.
    """
    depth = np.asarray(depth, dtype=np.float64)
    if distance_m <= 0:
        raise ValueError(f"the spacecraft-surface distance must be positive, got {distance_m}")
    reference = float(np.mean(depth)) if mean_depth is None else float(mean_depth)
    return -(depth / reference - 1.0) * distance_m


def heights_along_view(points: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """Metric heights of world points along the target's view direction.

    ``h = -a · X`` with ``a`` the camera's viewing axis: the coordinate of X toward
    the camera (world Z for a nadir camera), metres.

    Parameters
    ----------
    points : (N, 3) float
        World coordinates, metres (an aligned bundle).
    """
    return -(np.asarray(points, dtype=np.float64) @ camera.axis)


def target_samples(points: np.ndarray, camera: PinholeCamera, *, aligned: bool,
                   distance_m: float | None = None,
                   distortion: Sequence[float] = (0.0, 0.0)) -> TargetSamples:
    """Height samples of bundle points in the target image.

    Parameters
    ----------
    points : (N, 3) float
        Bundle points.
    camera : PinholeCamera
        Target camera of the bundle.
    aligned : bool
        The bundle is metric (world frame): heights along the view, metres.
        Otherwise eq. 2 with ``distance_m``.
    distance_m : float, optional
        Spacecraft–surface distance (required when not aligned).
    distortion : (2,) float
        Radial distortion of the target camera.

    Raises
    ------
    ProcessingError
        No point in the target image.
    ValueError
        ``distance_m`` missing for an unaligned bundle.
    """
    pixels, depth, index = project_to_target(points, camera, distortion)
    if aligned:
        heights = heights_along_view(np.asarray(points)[index], camera)
    else:
        if distance_m is None:
            raise ValueError("an unaligned bundle needs the spacecraft-surface distance")
        heights = heights_from_relative_depth(depth, distance_m)
    return TargetSamples(pixels=pixels, heights=heights, depth=depth, index=index)


def pixel_angle(camera: SensorModel) -> float:
    """Angular size of a pixel at the image centre, radians (through the interface).

    The look directions of the centre's neighbours half a pixel either way, along the
    sample and the line axes, are cut by the plane at unit distance along the centre's
    look direction; the mean of the two spacings is the pixel's angle (a pinhole:
    ``1 / focal_px`` when its principal point is the image centre).  A line scanner's
    detector is one line (its lines come from the motion), so only the sample axis
    counts there.
    """
    centre_line, centre_sample = 0.5 * camera.lines, 0.5 * camera.samples
    lines = centre_line + np.array([0.0, 0.0, 0.0, -0.5, 0.5])
    samples = centre_sample + np.array([0.0, -0.5, 0.5, 0.0, 0.0])
    look = np.asarray(camera.look_direction(lines, samples), dtype=np.float64)
    on_plane = look / (look @ look[0])[:, None]
    across = float(np.linalg.norm(on_plane[2] - on_plane[1]))
    if camera.kind == "linescan":
        return across
    return 0.5 * (across + float(np.linalg.norm(on_plane[4] - on_plane[3])))


def estimate_gsd(camera: SensorModel, *, aligned: bool, depth: np.ndarray,
                 distance_m: float | None) -> float:
    """Ground sampling distance of the target, metres per pixel: distance × pixel angle.

    The distance is the median depth of the points when the bundle is metric, else the
    given spacecraft–surface distance; the pixel angle comes from the sensor model's
    look directions (:func:`pixel_angle`).
    """
    distance = float(np.median(depth)) if aligned else float(distance_m or np.nan)
    if not np.isfinite(distance) or distance <= 0:
        raise ProcessingError("cannot estimate the GSD: give --gsd or the distance")
    return distance * pixel_angle(camera)
