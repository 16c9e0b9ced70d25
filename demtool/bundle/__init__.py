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

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.bundle.align import (  # noqa: F401
        align_to_centres,
        apply_similarity,
        umeyama,
    )
    from demtool.bundle.block import (  # noqa: F401
        BlockAdjustment,
        adjust_block,
        known_intrinsics,
    )
    from demtool.bundle.calibration import (  # noqa: F401
        self_calibrate,
    )
    from demtool.bundle.colmap import (  # noqa: F401
        CAMERA_MODELS,
        EXHAUSTIVE_MAX_IMAGES,
        MATCHERS,
        KnownIntrinsics,
        SfmOptions,
        colmap_camera_params,
        impose_intrinsics,
        run_sfm,
    )
    from demtool.bundle.inputs import (  # noqa: F401
        Block,
        block_from_paths,
        read_image_list,
        read_selection,
    )
    from demtool.bundle.model import (  # noqa: F401
        BundleResult,
        distort_normalized,
        image_report,
        project_points,
        radial_terms,
        reconstruction_to_result,
        reprojection_summary,
    )
    from demtool.bundle.runtime import (  # noqa: F401
        call_interruptibly,
        load_pycolmap,
        set_colmap_verbosity,
    )

_EXPORTS = {
    "align_to_centres": "demtool.bundle.align",
    "apply_similarity": "demtool.bundle.align",
    "umeyama": "demtool.bundle.align",
    "BlockAdjustment": "demtool.bundle.block",
    "adjust_block": "demtool.bundle.block",
    "known_intrinsics": "demtool.bundle.block",
    "self_calibrate": "demtool.bundle.calibration",
    "CAMERA_MODELS": "demtool.bundle.colmap",
    "EXHAUSTIVE_MAX_IMAGES": "demtool.bundle.colmap",
    "MATCHERS": "demtool.bundle.colmap",
    "KnownIntrinsics": "demtool.bundle.colmap",
    "SfmOptions": "demtool.bundle.colmap",
    "colmap_camera_params": "demtool.bundle.colmap",
    "impose_intrinsics": "demtool.bundle.colmap",
    "run_sfm": "demtool.bundle.colmap",
    "Block": "demtool.bundle.inputs",
    "block_from_paths": "demtool.bundle.inputs",
    "read_image_list": "demtool.bundle.inputs",
    "read_selection": "demtool.bundle.inputs",
    "BundleResult": "demtool.bundle.model",
    "distort_normalized": "demtool.bundle.model",
    "image_report": "demtool.bundle.model",
    "project_points": "demtool.bundle.model",
    "radial_terms": "demtool.bundle.model",
    "reconstruction_to_result": "demtool.bundle.model",
    "reprojection_summary": "demtool.bundle.model",
    "call_interruptibly": "demtool.bundle.runtime",
    "load_pycolmap": "demtool.bundle.runtime",
    "set_colmap_verbosity": "demtool.bundle.runtime",
}

__all__ = [
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


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'demtool.bundle' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
