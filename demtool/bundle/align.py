"""Similarity alignment of a reconstruction to known camera centres (Umeyama 1991)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from demtool.bundle.model import BundleResult
from demtool.errors import ProcessingError
from demtool.sensors.pinhole import PinholeCamera


def umeyama(source: np.ndarray, target: np.ndarray, *,
            with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``target ≈ s R source + t`` (Umeyama 1991).

    Parameters
    ----------
    source, target : (N, 3) float
        Corresponding points, N ≥ 3 and not collinear.
    with_scale : bool
        Estimate the scale (else s = 1).

    Returns
    -------
    scale : float
    rotation : (3, 3) float64
        Proper rotation (det = +1).
    translation : (3,) float64

    Raises
    ------
    ProcessingError
        Fewer than 3 points, or the points are (nearly) collinear.

    References
    ----------
    S. Umeyama, "Least-squares estimation of transformation parameters between two
    point patterns", IEEE TPAMI 13(4), 376-380, 1991, eqs. 34-42.
    """
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama expects two (N, 3) arrays, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ProcessingError(f"a similarity needs at least 3 camera centres, got {len(src)}")
    mean_src, mean_dst = src.mean(axis=0), dst.mean(axis=0)
    centred_src, centred_dst = src - mean_src, dst - mean_dst
    variance_src = np.mean(np.sum(centred_src**2, axis=1))
    covariance = centred_dst.T @ centred_src / len(src)
    u, singular, vt = np.linalg.svd(covariance)
    if singular[1] < 1e-9 * max(singular[0], 1e-300):
        raise ProcessingError("the camera centres are collinear: the rotation about "
                              "their line is undetermined")
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(singular) @ sign) / variance_src) if with_scale else 1.0
    translation = mean_dst - scale * rotation @ mean_src
    return scale, rotation, translation


def apply_similarity(result: BundleResult, scale: float, rotation: np.ndarray,
                     translation: np.ndarray) -> BundleResult:
    """The reconstruction mapped by ``X' = s R X + t`` (points and cameras), ``aligned``.

    A camera ``x_cam = R_c X + t_c`` becomes ``R_c' = R_c R^T``,
    ``t_c' = s t_c − R_c R^T t`` so that its camera coordinates scale with the model.
    """
    points = scale * result.points @ rotation.T + translation
    cameras = []
    for camera in result.cameras:
        R_new = camera.R @ rotation.T
        t_new = scale * camera.t - R_new @ translation
        cameras.append(PinholeCamera(K=camera.K, R=R_new, t=t_new, width=camera.width,
                                     height=camera.height))
    return replace(result, points=points, cameras=cameras, aligned=True)


def align_to_centres(result: BundleResult,
                     known_centres: Mapping[str, np.ndarray]) -> tuple[BundleResult, dict]:
    """Align a reconstruction to known camera centres (matched by image name).

    Parameters
    ----------
    result : BundleResult
    known_centres : mapping of view name to (3,) float
        Known camera centres, world frame, metres.

    Returns
    -------
    aligned : BundleResult
    report : dict
        ``scale``, number of centres used and their RMS residual (metres).

    Raises
    ------
    ProcessingError
        Fewer than 3 registered images have a known centre, or they are collinear.
    """
    names = [str(n) for n in result.image_names if str(n) in known_centres]
    if len(names) < 3:
        raise ProcessingError(
            f"alignment needs at least 3 registered images with known centres; found "
            f"{len(names)} ({', '.join(names) or 'none'}) among the registered "
            f"{', '.join(map(str, result.image_names))}")
    index = {str(n): i for i, n in enumerate(result.image_names)}
    model = np.array([result.cameras[index[n]].center for n in names])
    known = np.array([np.asarray(known_centres[n], dtype=np.float64) for n in names])
    scale, rotation, translation = umeyama(model, known)
    aligned = apply_similarity(result, scale, rotation, translation)
    moved = np.array([aligned.cameras[index[n]].center for n in names])
    rms = float(np.sqrt(np.mean(np.sum((moved - known) ** 2, axis=1))))
    return aligned, {"scale": scale, "centres_used": len(names), "centre_rms_m": rms}
