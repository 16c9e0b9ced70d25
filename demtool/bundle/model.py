"""A reconstruction in demtool's conventions: conversion, statistics, projection."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from demtool.bundle.colmap import CAMERA_MODELS
from demtool.errors import ProcessingError
from demtool.sensors.pinhole import PinholeCamera, from_pycolmap


@dataclass(frozen=True)
class BundleResult:
    """A reconstruction in demtool's conventions (see ``io.NPZ_SCHEMAS['bundle']``).

    Attributes
    ----------
    points : (N, 3) float64
        3-D points, model frame (metres in the world frame when ``aligned``).
    colors : (N,) float64
        Mean intensity of each point's track in the 8-bit images given to COLMAP.
    track_length : (N,) int64
        Number of images observing each point.
    reprojection_error : (N,) float64
        Mean reprojection error of each point over its track, pixels.
    image_names : (M,) str
        Registered images (view names), in input order.
    cameras : list of PinholeCamera
        Their cameras (world-to-camera), principal point in demtool's convention.
    distortion : (M, 2) float64
        Radial distortion (k1, k2) of COLMAP's models (zeros for pinhole models).
    target_index : int
        Index of the target image in ``image_names``.
    aligned : bool
        True when a similarity transform put the model in known metric coordinates.
    """

    points: np.ndarray
    colors: np.ndarray
    track_length: np.ndarray
    reprojection_error: np.ndarray
    image_names: np.ndarray
    cameras: list[PinholeCamera]
    distortion: np.ndarray
    target_index: int
    aligned: bool = False

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Arrays of a ``bundle`` NPZ (schema keys plus ``distortion``)."""
        return {
            "points": self.points,
            "colors": self.colors,
            "track_length": self.track_length.astype(np.int64),
            "reprojection_error": self.reprojection_error,
            "image_names": np.asarray(self.image_names, dtype=str),
            "K": np.stack([c.K for c in self.cameras]),
            "R": np.stack([c.R for c in self.cameras]),
            "t": np.stack([c.t for c in self.cameras]),
            "width": np.asarray([c.width for c in self.cameras], dtype=np.int64),
            "height": np.asarray([c.height for c in self.cameras], dtype=np.int64),
            "target_index": np.asarray(self.target_index, dtype=np.int64),
            "aligned": np.asarray(self.aligned),
            "distortion": self.distortion,
        }


def radial_terms(camera) -> tuple[float, float]:
    """Radial distortion (k1, k2) of a pycolmap Camera (zeros for pinhole models).

    Raises
    ------
    ProcessingError
        For a COLMAP model demtool cannot represent.
    """
    model = camera.model_name
    params = np.asarray(camera.params, dtype=np.float64)
    if model == "SIMPLE_RADIAL":
        return float(params[3]), 0.0
    if model == "RADIAL":
        return float(params[3]), float(params[4])
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        return 0.0, 0.0
    raise ProcessingError(f"COLMAP camera model {model} is not supported by demtool; "
                          f"use one of {', '.join(CAMERA_MODELS)}")


def reconstruction_to_result(reconstruction, file_to_name: Mapping[str, str],
                             order: Sequence[str], target_name: str | None) -> BundleResult:
    """Convert a pycolmap Reconstruction into a :class:`BundleResult`.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
    file_to_name : mapping of COLMAP image name (file name) to view name
    order : sequence of str
        View names in the order wanted in the output (the selection order).
    target_name : str or None
        The target view; must be registered.  None (a block without a target): the
        first registered view in ``order``.

    Raises
    ------
    ProcessingError
        If the target is not registered.
    """
    by_name = {}
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.image(image_id)
        by_name[file_to_name[image.name]] = image
    names = [n for n in order if n in by_name]
    if target_name is None and names:
        target_name = names[0]
    if target_name not in by_name:
        raise ProcessingError(f"the target image {target_name} was not registered "
                              f"(registered: {', '.join(names) or 'none'})")
    cameras, distortion = [], []
    for name in names:
        image = by_name[name]
        camera = reconstruction.camera(image.camera_id)
        cameras.append(from_pycolmap(image, camera))
        distortion.append(radial_terms(camera))

    count = reconstruction.num_points3D()
    points = np.empty((count, 3))
    colors = np.empty(count)
    track_length = np.empty(count, dtype=np.int64)
    errors = np.empty(count)
    for i, point in enumerate(reconstruction.points3D.values()):
        points[i] = point.xyz
        colors[i] = float(np.mean(point.color))
        track_length[i] = point.track.length()
        errors[i] = point.error
    return BundleResult(points=points, colors=colors, track_length=track_length,
                        reprojection_error=errors, image_names=np.asarray(names, dtype=str),
                        cameras=cameras, distortion=np.asarray(distortion, dtype=np.float64),
                        target_index=names.index(target_name), aligned=False)


def reprojection_summary(result: BundleResult) -> dict[str, float]:
    """Mean and 95th percentile of the per-point reprojection errors (pixels)."""
    errors = result.reprojection_error
    if len(errors) == 0:
        return {"mean_reprojection_error_px": float("nan"),
                "p95_reprojection_error_px": float("nan")}
    return {"mean_reprojection_error_px": float(np.mean(errors)),
            "p95_reprojection_error_px": float(np.percentile(errors, 95))}


def distort_normalized(xy: np.ndarray, k1: float, k2: float = 0.0) -> np.ndarray:
    """Apply COLMAP's radial distortion to normalised image coordinates.

    ``xy_d = xy * (1 + k1 r^2 + k2 r^4)`` with ``r^2 = x^2 + y^2`` (COLMAP's
    SIMPLE_RADIAL and RADIAL models).

    Parameters
    ----------
    xy : (N, 2) float
        Normalised coordinates x/z, y/z.
    """
    r2 = np.sum(xy * xy, axis=1, keepdims=True)
    return xy * (1.0 + k1 * r2 + k2 * r2 * r2)


def project_points(camera: PinholeCamera, points: np.ndarray,
                   distortion: Sequence[float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into a camera with optional radial distortion.

    Parameters
    ----------
    camera : PinholeCamera
    points : (N, 3) float
        World (model) coordinates.
    distortion : (2,) float
        Radial terms (k1, k2) as stored in ``bundle.npz``.

    Returns
    -------
    pixels : (N, 2) float64
        (u, v) in demtool's pixel convention; NaN for points behind the camera.
    depth : (N,) float64
        Camera z of each point (model units).
    """
    cam = camera.to_camera(np.atleast_2d(points))
    depth = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        normalized = cam[:, :2] / depth[:, None]
    normalized = distort_normalized(normalized, float(distortion[0]), float(distortion[1]))
    K = camera.K
    pixels = np.column_stack([K[0, 0] * normalized[:, 0] + K[0, 1] * normalized[:, 1] + K[0, 2],
                              K[1, 1] * normalized[:, 1] + K[1, 2]])
    pixels[depth <= 0] = np.nan
    return pixels, depth




def image_report(reconstruction, file_to_name: Mapping[str, str]) -> dict[str, dict]:
    """Per registered image: observations and reprojection residuals.

    Returns
    -------
    dict of view name to dict
        ``observations`` (image points with a 3-D point), ``mean_residual_px`` and
        ``rms_residual_px`` (length of observed − projected, pixels).
    """
    from demtool.bundle.calibration import observation_residuals

    report = {}
    for image_id, residuals in observation_residuals(reconstruction).items():
        name = file_to_name[reconstruction.image(image_id).name]
        lengths = np.hypot(residuals[:, 0], residuals[:, 1])
        report[name] = {
            "observations": int(len(residuals)),
            "mean_residual_px": float(lengths.mean()) if len(lengths) else float("nan"),
            "rms_residual_px": float(np.sqrt(np.mean(lengths**2))) if len(lengths)
            else float("nan"),
        }
    return report
