"""Structure from motion and bundle adjustment of a set of overlapping images (pycolmap).

The BAM route of the Rosetta NavCam study (Tyszkiewicz et al.): SIFT features,
pairwise matching with geometric verification, incremental mapping and bundle
adjustment, i.e. the minimisation of eq. 1 of the study,

    E = sum_i sum_j || x_ij - pi(K_j, R_j, t_j, X_i) ||^2,

the squared reprojection error over all 3-D points X_i and the cameras j that see them,
carried out by COLMAP (Schönberger & Frahm 2016) through pycolmap.

This module holds the pycolmap driver (which needs a scratch folder: COLMAP works
on an image folder and an SQLite database) and pure functions on the result:
conversion to demtool's camera convention and arrays, summary statistics, the
Umeyama (1991) similarity alignment to known camera centres, and projection with
COLMAP's radial distortion models.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from demtool.camera import PinholeCamera, from_pycolmap
from demtool.errors import ParameterError, ProcessingError
from demtool.logs import get_logger

log = get_logger(__name__)

#: COLMAP camera models demtool can represent: pinhole plus radial terms k1 (k2).
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL")
MATCHERS = ("auto", "exhaustive", "sequential")
#: ``matcher="auto"`` matches exhaustively up to this many images, sequentially above.
EXHAUSTIVE_MAX_IMAGES = 100


@dataclass(frozen=True)
class KnownIntrinsics:
    """Known intrinsics of one image, demtool convention (pixel centre at integer coords).

    Attributes
    ----------
    K : (3, 3) float64
        Intrinsic matrix in pixels.
    refine : bool
        Let bundle adjustment refine the focal length (principal point stays fixed).
    """

    K: np.ndarray
    refine: bool = False


@dataclass(frozen=True)
class SfmOptions:
    """Options of :func:`run_sfm`.

    Attributes
    ----------
    shared_camera : bool
        One camera (intrinsics) for all images, as for one instrument (COLMAP's
        camera mode SINGLE); False gives each image its own.
    camera_model : str
        COLMAP model, one of :data:`CAMERA_MODELS`.
    intrinsics : mapping of image name to KnownIntrinsics, optional
        Known intrinsics (all images, or none).
    matcher : str
        "exhaustive", "sequential" (images in the given order, with quadratic overlap),
        or "auto" (exhaustive up to :data:`EXHAUSTIVE_MAX_IMAGES` images).
    max_features : int
        Maximum SIFT features per image.
    seed : int
        Random seed of COLMAP's RANSAC and mapper.
    workers : int
        Threads (0 = all cores).
    """

    shared_camera: bool = True
    camera_model: str = "SIMPLE_RADIAL"
    intrinsics: Mapping[str, KnownIntrinsics] | None = None
    matcher: str = "auto"
    max_features: int = 8192
    seed: int = 0
    workers: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


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


# --------------------------------------------------------------------------------------
# pycolmap driver
# --------------------------------------------------------------------------------------


_colmap_verbose = False


def set_colmap_verbosity(verbose: bool) -> None:
    """Show COLMAP's own (glog) log on stderr only when ``verbose``."""
    import pycolmap

    global _colmap_verbose
    _colmap_verbose = bool(verbose)
    pycolmap.logging.minloglevel = 0 if verbose else 3
    pycolmap.logging.stderrthreshold = 0 if verbose else 3
    pycolmap.logging.logtostderr = bool(verbose)


@contextlib.contextmanager
def _colmap_output() -> Iterator[None]:
    """Silence what COLMAP's C++ code writes to the stderr file descriptor, unless
    verbose (some of its messages ignore glog's level flags)."""
    if _colmap_verbose:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def colmap_camera_params(model: str, K: np.ndarray) -> str:
    """COLMAP parameter string for ``model`` from a demtool intrinsic matrix.

    COLMAP puts the centre of the top-left pixel at (0.5, 0.5): the principal point
    is shifted by +0.5 px.  Distortion terms start at zero.
    """
    fx, fy = float(K[0, 0]), float(K[1, 1])
    cx, cy = float(K[0, 2]) + 0.5, float(K[1, 2]) + 0.5
    values = {
        "SIMPLE_PINHOLE": [0.5 * (fx + fy), cx, cy],
        "PINHOLE": [fx, fy, cx, cy],
        "SIMPLE_RADIAL": [0.5 * (fx + fy), cx, cy, 0.0],
        "RADIAL": [0.5 * (fx + fy), cx, cy, 0.0, 0.0],
    }[model]
    return ",".join(repr(v) for v in values)


def _set_known_intrinsics(database_path: Path, model: str,
                          intrinsics: Mapping[str, KnownIntrinsics],
                          file_to_name: Mapping[str, str]) -> None:
    """Write known intrinsics into the cameras of a COLMAP database."""
    import pycolmap

    database = pycolmap.Database.open(database_path)
    try:
        cameras = {c.camera_id: c for c in database.read_all_cameras()}
        for image in database.read_all_images():
            camera = cameras[image.camera_id]
            known = intrinsics[file_to_name[image.name]]
            camera.set_params_from_string(colmap_camera_params(model, known.K))
            camera.has_prior_focal_length = True
            database.update_camera(camera)
    finally:
        database.close()


def run_sfm(image_folder: str | os.PathLike, files: Mapping[str, str],
            work_folder: str | os.PathLike, options: SfmOptions):
    """Features, matching and incremental mapping with bundle adjustment (pycolmap).

    Parameters
    ----------
    image_folder : path-like
        Folder holding the images COLMAP reads (8-bit images).
    files : mapping of file name to image name
        The files of ``image_folder`` to use and the view names they stand for.
    work_folder : path-like
        Scratch folder for COLMAP's database and models.
    options : SfmOptions

    Returns
    -------
    reconstructions : list of pycolmap.Reconstruction
        Every model COLMAP built, largest (most registered images, then most points)
        first.  Empty if mapping failed.
    """
    import pycolmap

    if options.camera_model not in CAMERA_MODELS:
        raise ParameterError(f"unknown camera model {options.camera_model!r}; "
                             f"should be one of {', '.join(CAMERA_MODELS)}")
    if options.matcher not in MATCHERS:
        raise ParameterError(f"unknown matcher {options.matcher!r}; "
                             f"should be one of {', '.join(MATCHERS)}")
    work = Path(work_folder)
    database_path = work / "database.db"
    threads = options.workers if options.workers > 0 else -1
    intrinsics = options.intrinsics
    shared_known = False
    if intrinsics:
        matrices = [intrinsics[name].K for name in files.values()]
        shared_known = all(np.allclose(m, matrices[0]) for m in matrices)

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = options.camera_model
    if intrinsics and shared_known and options.shared_camera:
        reader.camera_params = colmap_camera_params(options.camera_model, matrices[0])
    mode = (pycolmap.CameraMode.SINGLE
            if options.shared_camera and (not intrinsics or shared_known)
            else pycolmap.CameraMode.PER_IMAGE)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.max_num_features = int(options.max_features)
    extraction.use_gpu = False
    log.info("extracting SIFT features from %d images", len(files))
    with _colmap_output():
        pycolmap.extract_features(database_path, image_folder, image_names=list(files),
                                  camera_mode=mode, reader_options=reader,
                                  extraction_options=extraction, device=pycolmap.Device.cpu)
    if intrinsics and mode == pycolmap.CameraMode.PER_IMAGE:
        _set_known_intrinsics(database_path, options.camera_model, intrinsics, files)

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    matching.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(options.seed)
    matcher = options.matcher
    if matcher == "auto":
        matcher = "exhaustive" if len(files) <= EXHAUSTIVE_MAX_IMAGES else "sequential"
    log.info("matching features (%s)", matcher)
    if matcher == "exhaustive":
        with _colmap_output():
            pycolmap.match_exhaustive(database_path, matching_options=matching,
                                      verification_options=verification,
                                      device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = 10
        pairing.quadratic_overlap = True
        with _colmap_output():
            pycolmap.match_sequential(database_path, matching_options=matching,
                                      pairing_options=pairing,
                                      verification_options=verification,
                                      device=pycolmap.Device.cpu)

    pipeline = pycolmap.IncrementalPipelineOptions()
    pipeline.random_seed = int(options.seed)
    pipeline.num_threads = threads
    pipeline.min_model_size = 2
    if intrinsics:
        refine = any(k.refine for k in intrinsics.values())
        pipeline.ba_refine_focal_length = refine
        pipeline.ba_refine_principal_point = False
        pipeline.ba_refine_extra_params = refine or options.camera_model in (
            "SIMPLE_RADIAL", "RADIAL")
        pipeline.mapper.abs_pose_refine_focal_length = refine
    for key, value in options.extra.items():
        setattr(pipeline, key, value)
    log.info("incremental mapping and bundle adjustment")
    with _colmap_output():
        models = pycolmap.incremental_mapping(database_path, image_folder, work / "sparse",
                                              options=pipeline)
    return sorted(models.values(),
                  key=lambda r: (r.num_reg_images(), r.num_points3D()), reverse=True)


def impose_intrinsics(reconstruction, intrinsics: Mapping[str, KnownIntrinsics],
                      file_to_name: Mapping[str, str], *, workers: int = 0) -> None:
    """Replace the cameras' intrinsics by known ones (PINHOLE) and re-run global BA.

    The fallback when COLMAP cannot initialise with the known intrinsics fixed (very
    narrow fields of view, where the calibrated two-view geometry of a nearly planar
    scene is degenerate): map with free intrinsics, then impose the known ones and
    re-adjust poses and points (focal lengths refined only if asked).  Changes
    ``reconstruction`` in place.
    """
    import pycolmap

    refine = any(k.refine for k in intrinsics.values())
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.image(image_id)
        camera = reconstruction.camera(image.camera_id)
        K = intrinsics[file_to_name[image.name]].K
        camera.model = pycolmap.CameraModelId.PINHOLE
        camera.params = [float(v) for v in colmap_camera_params("PINHOLE", K).split(",")]
    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_focal_length = refine
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.ceres.solver_options.num_threads = workers if workers > 0 else -1
    with _colmap_output():
        pycolmap.bundle_adjustment(reconstruction, options)
    reconstruction.update_point_3d_errors()


def refine_second_radial_term(reconstruction, *, workers: int = 0) -> bool:
    """Free a second radial distortion term and re-run global bundle adjustment.

    Incremental mapping with COLMAP's SIMPLE_RADIAL model (one term k) is robust on
    narrow fields of view, where a two-term model can make the first registrations
    fail; the second term k2 (RADIAL model) is then estimated in one final global
    bundle adjustment of the complete model, starting from k2 = 0.  Changes
    ``reconstruction`` in place.

    Returns
    -------
    bool
        True if any camera was converted and the model re-adjusted.
    """
    import pycolmap

    converted = False
    for camera in reconstruction.cameras.values():
        if camera.model_name != "SIMPLE_RADIAL":
            continue
        params = [float(v) for v in camera.params]
        camera.model = pycolmap.CameraModelId.RADIAL
        camera.params = params + [0.0]
        converted = True
    if not converted:
        return False
    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.ceres.solver_options.num_threads = workers if workers > 0 else -1
    with _colmap_output():
        pycolmap.bundle_adjustment(reconstruction, options)
    reconstruction.update_point_3d_errors()
    return True


# --------------------------------------------------------------------------------------
# Conversion and statistics (pure)
# --------------------------------------------------------------------------------------


def _radial_terms(camera) -> tuple[float, float]:
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
                             order: Sequence[str], target_name: str) -> BundleResult:
    """Convert a pycolmap Reconstruction into a :class:`BundleResult`.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
    file_to_name : mapping of COLMAP image name (file name) to view name
    order : sequence of str
        View names in the order wanted in the output (the selection order).
    target_name : str
        The target view; must be registered.

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
    if target_name not in by_name:
        raise ProcessingError(f"the target image {target_name} was not registered "
                              f"(registered: {', '.join(names) or 'none'})")
    cameras, distortion = [], []
    for name in names:
        image = by_name[name]
        camera = reconstruction.camera(image.camera_id)
        cameras.append(from_pycolmap(image, camera))
        distortion.append(_radial_terms(camera))

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


# --------------------------------------------------------------------------------------
# Similarity alignment (Umeyama 1991)
# --------------------------------------------------------------------------------------


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
