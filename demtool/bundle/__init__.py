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

Names are imported lazily (PEP 562), so ``demtool bundle --help`` and the
parameter module ``demtool.bundle.params`` do not pull in numba, OpenCV or pycolmap.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "align": ("align_to_centres", "apply_similarity", "umeyama"),
    "block": ("BlockAdjustment", "adjust_block", "check_focal_px", "known_intrinsics"),
    "calibration": ("self_calibrate",),
    "colmap": ("CAMERA_MODELS", "EXHAUSTIVE_MAX_IMAGES", "MATCHERS", "KnownIntrinsics",
        "SfmOptions", "colmap_camera_params", "impose_intrinsics", "run_sfm"),
    "inputs": ("Block", "block_from_paths", "read_image_list", "read_selection"),
    "model": ("BundleResult", "distort_normalized", "image_report", "project_points",
        "radial_terms", "reconstruction_to_result", "reprojection_summary"),
    "runtime": ("call_interruptibly", "load_pycolmap", "set_colmap_verbosity"),
    "offsets": ("PoseOffset",),
    "priors": ("AdjustedSensor", "Observations", "PriorAdjustment", "adjust_with_priors",
        "triangulate"),
    "sensorblock": ("SensorBlockAdjustment", "adjust_sensor_block", "local_pinhole"),
    "ties": ("footprint", "image_pairs", "overlapping_pairs", "tie_points"),
    "tierefine": ("RefineReport", "reference_observations", "refine_observations"),
    "writeback": ("adjust_isd", "adjust_tsai", "model_isd"),
})
