"""pycolmap driver of `demtool bundle`: features, matching, incremental mapping, BA.

COLMAP (Schönberger & Frahm 2016) works on an image folder and an SQLite database, so
:func:`run_sfm` needs a scratch folder; the other functions adjust a
``pycolmap.Reconstruction`` in place.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demtool.bundle.runtime import (
    bundle_adjustment_options,
    call_interruptibly,
    load_pycolmap,
    run_in_child,
)
from demtool.errors import ParameterError
from demtool.logs import get_logger

log = get_logger(__name__)

#: COLMAP camera models demtool can represent: pinhole plus radial terms k1 (k2).
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL")
MATCHERS = ("auto", "exhaustive", "sequential", "pairs")
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
        "auto" (exhaustive up to :data:`EXHAUSTIVE_MAX_IMAGES` images), or "pairs"
        (only the image pairs in ``pairs``: the hook of footprint-based "spatial"
        matching, see :func:`demtool.bundle.ties.overlapping_pairs`).
    pairs : sequence of (str, str), optional
        Image (view) name pairs to match when ``matcher`` is "pairs".
    max_features : int
        Maximum SIFT features per image.
    features : str
        "standard" (COLMAP's SIFT), "rich" (:data:`demtool.bundle.register.RICH_SIFT`
        and guided matching: weak texture, wide angles between views) or "auto"
        (standard, then a second pass with rich features when views are left out).
    seed : int
        Random seed of COLMAP's RANSAC and mapper.
    workers : int
        Threads (0 = all cores) of feature extraction and matching, which give the
        same features and matches with any number (each image and each pair is one
        task with its own seeded RANSAC); of mapping and bundle adjustment too when
        not ``reproducible``.
    reproducible : bool
        Map and adjust with one thread, so that the same inputs give the same model
        bit for bit (:func:`mapping_threads`).  With several threads Ceres sums the
        normal equations in whatever order the threads finish, and the last bits of
        the poses differ from run to run, which incremental mapping can amplify (a
        point triangulated or not, an image registered in another order).
    extra : dict
        ``pycolmap.IncrementalPipelineOptions`` attributes to override (expert use).
    """

    shared_camera: bool = True
    camera_model: str = "SIMPLE_RADIAL"
    intrinsics: Mapping[str, KnownIntrinsics] | None = None
    matcher: str = "auto"
    pairs: Sequence[tuple[str, str]] | None = None
    max_features: int = 8192
    features: str = "auto"
    seed: int = 0
    workers: int = 0
    reproducible: bool = True
    extra: dict[str, Any] = field(default_factory=dict)


def mapping_threads(options: SfmOptions) -> int:
    """Threads of incremental mapping and bundle adjustment (COLMAP's convention: -1 =
    all cores): one when ``options.reproducible``, else ``options.workers``."""
    if options.reproducible:
        return 1
    return options.workers if options.workers > 0 else -1


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
    pycolmap = load_pycolmap()
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


def _match(database_path: Path, files: Mapping[str, str], options: SfmOptions,
           work: Path, threads: int, rich: bool = False) -> None:
    """Pairwise matching with geometric verification (the matcher of ``options``;
    guided by the verified two-view geometry when ``rich``)."""
    pycolmap = load_pycolmap()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    matching.use_gpu = False
    matching.guided_matching = rich
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(options.seed)
    matcher = options.matcher
    if matcher == "auto":
        matcher = "exhaustive" if len(files) <= EXHAUSTIVE_MAX_IMAGES else "sequential"
    log.info("matching features (%s)", matcher)
    if matcher == "exhaustive":
        run_in_child(pycolmap.match_exhaustive, database_path, matching_options=matching,
                           verification_options=verification, device=pycolmap.Device.cpu)
    elif matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = 10
        pairing.quadratic_overlap = True
        run_in_child(pycolmap.match_sequential, database_path, matching_options=matching,
                           pairing_options=pairing, verification_options=verification,
                           device=pycolmap.Device.cpu)
    else:
        name_to_file = {name: file for file, name in files.items()}
        unknown = sorted({n for pair in options.pairs or () for n in pair} - set(name_to_file))
        if unknown:
            raise ParameterError(f"pairs name unknown images: {', '.join(unknown)}")
        pair_file = work / "pairs.txt"
        pair_file.write_text("".join(f"{name_to_file[a]} {name_to_file[b]}\n"
                                     for a, b in options.pairs or ()))
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(pair_file)
        run_in_child(pycolmap.match_image_pairs, database_path, matching_options=matching,
                           pairing_options=pairing, verification_options=verification,
                           device=pycolmap.Device.cpu)


def _pipeline_options(options: SfmOptions, threads: int):
    pycolmap = load_pycolmap()
    pipeline = pycolmap.IncrementalPipelineOptions()
    pipeline.random_seed = int(options.seed)
    pipeline.num_threads = threads
    pipeline.mapper.num_threads = threads
    pipeline.mapper.random_seed = int(options.seed)
    pipeline.triangulation.random_seed = int(options.seed)
    pipeline.min_model_size = 2
    if options.intrinsics:
        refine = any(k.refine for k in options.intrinsics.values())
        pipeline.ba_refine_focal_length = refine
        pipeline.ba_refine_principal_point = False
        pipeline.ba_refine_extra_params = refine or options.camera_model in (
            "SIMPLE_RADIAL", "RADIAL")
        pipeline.mapper.abs_pose_refine_focal_length = refine
    for key, value in options.extra.items():
        owner, _, name = key.rpartition(".")
        setattr(getattr(pipeline, owner) if owner else pipeline, name, value)
    return pipeline


def _sorted_models(models) -> list:
    return sorted(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()),
                  reverse=True)


def _map(database_path: Path, image_folder, output: Path, pipeline,
         input_path: Path | None = None) -> list:
    """Incremental mapping in a child process (interruptible); the models COLMAP wrote
    into ``output``, largest first."""
    pycolmap = load_pycolmap()
    output.mkdir(parents=True, exist_ok=True)
    kwargs = {"input_path": input_path} if input_path is not None else {}
    run_in_child(pycolmap.incremental_mapping, database_path, image_folder, output,
                 options=pipeline, **kwargs)
    models = {}
    for folder in sorted(output.iterdir()):
        if folder.is_dir() and (folder / "images.bin").is_file():
            models[folder.name] = pycolmap.Reconstruction(folder)
    return _sorted_models(models)


def run_sfm(image_folder: str | os.PathLike, files: Mapping[str, str],
            work_folder: str | os.PathLike, options: SfmOptions) -> tuple[list, dict]:
    """Features, matching and incremental mapping with bundle adjustment (pycolmap).

    With known intrinsics (``options.intrinsics``) the images are registered with the
    intrinsics fixed, in one mapping pass.  Images COLMAP leaves out are retried one
    by one (COLMAP continues from the model with relaxed absolute-pose thresholds;
    registered images keep their poses while they are added), never by re-mapping the
    whole block.  Only when no two images can start a model with the intrinsics fixed
    (very narrow fields of view, where the calibrated two-view geometry of a nearly
    planar scene is degenerate) is the block mapped with free intrinsics; the caller
    then imposes the known ones (:func:`impose_intrinsics`).

    With ``options.features`` "auto", a block that leaves views out after the retry
    is mapped again from scratch with rich features and guided matching
    (:mod:`demtool.bundle.register`), starting (free intrinsics) from the focal
    length of the first model; the model with more registered images is kept.  Each
    view still left out gets the reason (log and report).

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
    report : dict
        Of the pass whose model is kept: ``mapping_passes`` (1, or 2 when the
        free-intrinsics fallback ran), ``retried`` (images retried one by one),
        ``free_fallback`` (bool), ``features`` ("standard" or "rich"),
        ``focal_start_px`` (the focal length the pass started from, from the first
        pass's model; None: COLMAP's 1.2 × the image size, or the known one); and
        ``feature_passes`` (the kinds of features tried), ``unregistered_reasons``
        (:func:`demtool.bundle.register.unregistered_reasons`).
    """
    from demtool.bundle import register

    if options.camera_model not in CAMERA_MODELS:
        raise ParameterError(f"unknown camera model {options.camera_model!r}; "
                             f"should be one of {', '.join(CAMERA_MODELS)}")
    if options.matcher not in MATCHERS:
        raise ParameterError(f"unknown matcher {options.matcher!r}; "
                             f"should be one of {', '.join(MATCHERS)}")
    if options.features not in register.FEATURES:
        raise ParameterError(f"unknown features {options.features!r}; "
                             f"should be one of {', '.join(register.FEATURES)}")
    work = Path(work_folder)
    kinds = ["rich"] if options.features == "rich" else \
        ["standard", "rich"] if options.features == "auto" else ["standard"]
    models: list = []
    report: dict = {}
    ran = []
    for kind in kinds:
        pass_work = work / kind
        pass_work.mkdir(exist_ok=True)
        start = None
        if kind == "rich" and models:
            log.info("%d of %d images registered: mapping again with rich features "
                     "(affine-shaped DSP-SIFT, low peak threshold, guided matching)",
                     models[0].num_reg_images(), len(files))
            start = _focal_of(models[0], options)
        pass_models, pass_report = _sfm_pass(image_folder, files, pass_work, options,
                                             rich=kind == "rich", focal_start=start)
        ran.append(kind)
        pass_report.update(features=kind, focal_start_px=start,
                           database=str(pass_work / "database.db"))
        if not report or (pass_models and (not models or
                                           _size(pass_models[0]) > _size(models[0]))):
            models, report = pass_models, pass_report
        if models and models[0].num_reg_images() == len(files):
            break
    report["feature_passes"] = ran
    pipeline = _pipeline_options(options, 1)
    reasons = register.unregistered_reasons(
        report["database"],
        models[0] if models else None, files,
        min_matches=pipeline.min_num_matches,
        min_inliers=pipeline.mapper.abs_pose_min_num_inliers)
    report.pop("database", None)
    report["unregistered_reasons"] = reasons
    # a failed block is one error line (the caller's); the reasons then go to -v's log
    report_level = log.warning if models and models[0].num_reg_images() >= 2 else log.info
    for name, row in reasons.items():
        report_level("%s not registered: %s", name, row["reason"])
    return models, report


def _size(model) -> tuple[int, int]:
    return model.num_reg_images(), model.num_points3D()


def _focal_of(model, options: SfmOptions) -> float | None:
    """The focal length (pixels) a first model found, to start the next pass from:
    only with free intrinsics and at least three registered images (two views do not
    determine it)."""
    if options.intrinsics or model.num_reg_images() < 3:
        return None
    camera = model.camera(model.image(model.reg_image_ids()[0]).camera_id)
    return float(np.mean(np.asarray(camera.params)[camera.focal_length_idxs()]))


def _sfm_pass(image_folder, files: Mapping[str, str], work: Path, options: SfmOptions, *,
              rich: bool, focal_start: float | None) -> tuple[list, dict]:
    """One pass of :func:`run_sfm`: its own database, features of one kind, mapping."""
    from demtool.bundle import register

    pycolmap = load_pycolmap()
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
    elif focal_start is not None and options.shared_camera:
        width, height = _image_size(Path(image_folder) / next(iter(files)))
        reader.camera_params = colmap_camera_params(
            options.camera_model, np.array([[focal_start, 0, (width - 1) / 2],
                                            [0, focal_start, (height - 1) / 2], [0, 0, 1]]))
    mode = (pycolmap.CameraMode.SINGLE
            if options.shared_camera and (not intrinsics or shared_known)
            else pycolmap.CameraMode.PER_IMAGE)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.max_num_features = int(options.max_features)
    extraction.use_gpu = False
    register.sift_options(extraction, rich)
    log.info("extracting %sSIFT features from %d images", "rich " if rich else "",
             len(files))
    # Images enter the database one by one in the given order before the threads
    # extract their features: the threads would otherwise number them in the order
    # they finish, and COLMAP's mapping depends on the numbering.
    pycolmap.Database.open(database_path).close()
    run_in_child(pycolmap.import_images, database_path, image_folder, camera_mode=mode,
                 image_names=list(files), options=reader)
    run_in_child(pycolmap.extract_features, database_path, image_folder,
                       image_names=list(files), camera_mode=mode, reader_options=reader,
                       extraction_options=extraction, device=pycolmap.Device.cpu)
    if intrinsics:
        _set_known_intrinsics(database_path, options.camera_model, intrinsics, files)
    _match(database_path, files, options, work, threads, rich=rich)

    pipeline = _pipeline_options(options, mapping_threads(options))
    report: dict = {"mapping_passes": 1, "retried": [], "free_fallback": False}
    log.info("incremental mapping and bundle adjustment%s",
             " (known intrinsics, fixed)" if intrinsics else "")
    models = _map(database_path, image_folder, work / "sparse", pipeline)
    if models and models[0].num_reg_images() < len(files):
        models[0] = _retry_left_out(models[0], database_path, image_folder, work, pipeline,
                                    files, report)
    elif intrinsics and not models:
        log.warning("no image pair starts a model with the known intrinsics fixed (a "
                    "narrow field of view?); mapping with free intrinsics, imposing the "
                    "known ones after")
        # The database's two-view geometries were verified with the known (calibrated)
        # cameras, which is what failed: start afresh with free cameras.
        free_options = SfmOptions(shared_camera=options.shared_camera,
                                  camera_model="SIMPLE_RADIAL", matcher=options.matcher,
                                  pairs=options.pairs, max_features=options.max_features,
                                  features="rich" if rich else "standard",
                                  seed=options.seed, workers=options.workers,
                                  reproducible=options.reproducible,
                                  extra=dict(options.extra))
        free_work = work / "free"
        free_work.mkdir()
        models, _ = _sfm_pass(image_folder, files, free_work, free_options, rich=rich,
                              focal_start=None)
        report.update(mapping_passes=2, free_fallback=True)
    return models, report


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return int(image.shape[1]), int(image.shape[0])


def _retry_left_out(model, database_path: Path, image_folder, work: Path, pipeline,
                    files: Mapping[str, str], report: dict):
    """Continue mapping from ``model`` to register the images it left out.

    The registered images keep their poses while COLMAP tries the others with relaxed
    absolute-pose thresholds (fewer inliers, a larger error); a final global bundle
    adjustment of the continued model follows in COLMAP.  Known intrinsics stay
    fixed.  Returns the larger of the two models.
    """
    pycolmap = load_pycolmap()
    registered = {model.image(i).name for i in model.reg_image_ids()}
    left_out = [files[f] for f in files if f not in registered]
    log.info("retrying %d image(s) COLMAP left out: %s", len(left_out), ", ".join(left_out))
    report["retried"] = left_out
    start = work / "start"
    start.mkdir(exist_ok=True)
    model.write(start)
    retry = pycolmap.IncrementalPipelineOptions(pipeline.todict())
    retry.fix_existing_frames = True
    retry.mapper.abs_pose_min_num_inliers = max(10, pipeline.mapper.abs_pose_min_num_inliers // 3)
    retry.mapper.abs_pose_min_inlier_ratio = 0.5 * pipeline.mapper.abs_pose_min_inlier_ratio
    retry.mapper.abs_pose_max_error = 2.0 * pipeline.mapper.abs_pose_max_error
    retry.mapper.max_reg_trials = pipeline.mapper.max_reg_trials + 3
    continued = _map(database_path, image_folder, work / "retry", retry, input_path=start)
    if continued and continued[0].num_reg_images() > model.num_reg_images():
        return continued[0]
    return model


def impose_intrinsics(reconstruction, intrinsics: Mapping[str, KnownIntrinsics],
                      file_to_name: Mapping[str, str], *, workers: int = 0) -> None:
    """Replace the cameras' intrinsics by known ones (PINHOLE) and re-run global BA.

    The fallback when COLMAP cannot initialise with the known intrinsics fixed (very
    narrow fields of view, where the calibrated two-view geometry of a nearly planar
    scene is degenerate): map with free intrinsics, then impose the known ones and
    re-adjust poses and points (focal lengths refined only if asked).  Changes
    ``reconstruction`` in place.  ``workers``: threads of the adjustment (0 = all
    cores; 1 for a reproducible result, see :func:`mapping_threads`).
    """
    pycolmap = load_pycolmap()
    refine = any(k.refine for k in intrinsics.values())
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.image(image_id)
        camera = reconstruction.camera(image.camera_id)
        K = intrinsics[file_to_name[image.name]].K
        camera.model = pycolmap.CameraModelId.PINHOLE
        camera.params = [float(v) for v in colmap_camera_params("PINHOLE", K).split(",")]
    options = bundle_adjustment_options(focal_length=refine, principal_point=False,
                                        extra_params=False, workers=workers)
    call_interruptibly(pycolmap.bundle_adjustment, reconstruction, options, cancellable=False)
    reconstruction.update_point_3d_errors()
