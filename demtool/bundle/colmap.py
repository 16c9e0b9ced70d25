"""pycolmap driver of `demtool bundle`: features, matching, incremental mapping, BA.

COLMAP (Schönberger & Frahm 2016) works on an image folder and an SQLite database, so
:func:`run_sfm` needs a scratch folder; the other functions adjust a
``pycolmap.Reconstruction`` in place.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import ParameterError
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
    extra : dict
        ``pycolmap.IncrementalPipelineOptions`` attributes to override (expert use).
    """

    shared_camera: bool = True
    camera_model: str = "SIMPLE_RADIAL"
    intrinsics: Mapping[str, KnownIntrinsics] | None = None
    matcher: str = "auto"
    max_features: int = 8192
    seed: int = 0
    workers: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


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
    if intrinsics:
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
        owner, _, name = key.rpartition(".")
        setattr(getattr(pipeline, owner) if owner else pipeline, name, value)
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


