"""Structure from motion and bundle adjustment of a set of overlapping images (pycolmap).

The BAM route of the Rosetta NavCam study (Tyszkiewicz et al.): SIFT features,
pairwise matching with geometric verification, incremental mapping and bundle
adjustment, i.e. the minimisation of eq. 1 of the study,

    E = sum_i sum_j || x_ij - pi(K_j, R_j, t_j, X_i) ||^2,

the squared reprojection error over all 3-D points X_i and the cameras j that see them,
carried out by COLMAP (Schönberger & Frahm 2016) through pycolmap.

With sensor models (``bundle --sensors``), :mod:`demtool.bundle.priors` adjusts a
constant body-fixed pose offset per image with position/pointing priors instead
(tie points from :mod:`demtool.bundle.ties`, write-back in :mod:`demtool.bundle.writeback`).

This module holds the pycolmap driver (which needs a scratch folder: COLMAP works
on an image folder and an SQLite database) and pure functions on the result:
conversion to demtool's camera convention and arrays, summary statistics, the
Umeyama (1991) similarity alignment to known camera centres, and projection with
COLMAP's radial distortion models.
"""

from demtool.bundle.align import align_to_centres, apply_similarity, umeyama
from demtool.bundle.block import BlockAdjustment, adjust_block, known_intrinsics
from demtool.bundle.calibration import self_calibrate
from demtool.bundle.colmap import (
    CAMERA_MODELS,
    EXHAUSTIVE_MAX_IMAGES,
    MATCHERS,
    KnownIntrinsics,
    SfmOptions,
    colmap_camera_params,
    impose_intrinsics,
    run_sfm,
)
from demtool.bundle.inputs import Block, block_from_paths, read_image_list, read_selection
from demtool.bundle.model import (
    BundleResult,
    distort_normalized,
    image_report,
    project_points,
    radial_terms,
    reconstruction_to_result,
    reprojection_summary,
)
from demtool.bundle.priors import (
    AdjustedSensor,
    Observations,
    PoseOffset,
    PriorAdjustment,
    adjust_with_priors,
    triangulate,
)
from demtool.bundle.runtime import call_interruptibly, load_pycolmap, set_colmap_verbosity
from demtool.bundle.sensorblock import SensorBlockAdjustment, adjust_sensor_block, local_pinhole
from demtool.bundle.ties import footprint, image_pairs, overlapping_pairs, tie_points
from demtool.bundle.writeback import adjust_isd, adjust_tsai, model_isd

__all__ = [
    "AdjustedSensor",
    "Observations",
    "PoseOffset",
    "PriorAdjustment",
    "SensorBlockAdjustment",
    "adjust_isd",
    "adjust_sensor_block",
    "adjust_tsai",
    "adjust_with_priors",
    "footprint",
    "image_pairs",
    "local_pinhole",
    "model_isd",
    "overlapping_pairs",
    "tie_points",
    "triangulate",
    "CAMERA_MODELS",
    "EXHAUSTIVE_MAX_IMAGES",
    "MATCHERS",
    "Block",
    "BlockAdjustment",
    "BundleResult",
    "adjust_block",
    "block_from_paths",
    "image_report",
    "known_intrinsics",
    "read_image_list",
    "read_selection",
    "self_calibrate",
    "KnownIntrinsics",
    "SfmOptions",
    "align_to_centres",
    "apply_similarity",
    "call_interruptibly",
    "load_pycolmap",
    "colmap_camera_params",
    "distort_normalized",
    "impose_intrinsics",
    "project_points",
    "radial_terms",
    "reconstruction_to_result",
    "reprojection_summary",
    "run_sfm",
    "set_colmap_verbosity",
    "umeyama",
]
