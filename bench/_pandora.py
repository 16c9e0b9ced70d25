"""CNES Pandora with libSGM, the second reference of the stereo benchmark (issue 26).

Two configurations, both Pandora's sample SGM pipeline: census 5×5, SGM with P1 8 /
P2 32 (constant), winner-takes-all, V-fit sub-pixel refinement, 3×3 median, and the
accurate cross-checking (threshold 1 px); the second adds
``"interpolated_disparity": "sgm"`` (occlusions from the background, mismatches by the
median of 8 directions; Hirschmüller 2008 §3.4), so it answers every pixel.

Pandora is an optional bench extra (``pip install 'demtool[bench-pandora]'``, i.e.
``pandora[sgm]``); :func:`available` says whether it can be imported, and the benchmark
skips its columns cleanly when not.  Pandora's convention is ``x_right = x_left + d``:
the range is searched as ``−(max) … −(min)`` and the result negated.

Reference: Cournet, M. et al. (2020), Ground truth generation and disparity estimation
for optical satellite imagery, ISPRS Archives XLIII-B2, 127–134; https://github.com/CNES/Pandora.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

CONFIGURATIONS = {
    "Pandora": {},
    "Pandora+interp": {"interpolated_disparity": "sgm"},
}


def available() -> str:
    """"" when Pandora and its libSGM plugin import, else why not (one line)."""
    try:
        import pandora  # noqa: F401
        import pandora_plugin_libsgm  # noqa: F401
    except Exception as error:  # an optional extra: any import failure means "skip"
        return f"{type(error).__name__}: {error}"
    return ""


def _write(path: Path, image: np.ndarray) -> None:
    import rasterio

    with warnings.catch_warnings():  # an image frame, not a map: no geotransform
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", width=image.shape[1],
                           height=image.shape[0], count=1, dtype="float32") as dst:
            dst.write(image.astype(np.float32), 1)


def pandora_sgm(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int,
                interpolation: str | None = None) -> tuple[np.ndarray, float]:
    """Pandora's libSGM pipeline on a pair; (disparity in demtool's convention, NaN =
    invalid, seconds of Pandora's run without the file writing).

    Pixels whose validity mask has an invalid bit (``Criteria.PANDORA_MSK_PIXEL_INVALID``:
    no data, occlusion, mismatch …) are NaN; filled ones keep their value.
    """
    import pandora
    import rasterio
    from pandora.check_configuration import check_conf
    from pandora.constants import Criteria
    from pandora.img_tools import create_dataset_from_inputs
    from pandora.state_machine import PandoraMachine

    validation = {"validation_method": "cross_checking_accurate",
                  "cross_checking_threshold": 1.0}
    if interpolation:
        validation["interpolated_disparity"] = interpolation
    high = min_disparity + num_disparities - 1
    with tempfile.TemporaryDirectory() as folder:
        paths = Path(folder) / "left.tif", Path(folder) / "right.tif"
        _write(paths[0], left)
        _write(paths[1], right)
        cfg = {
            "input": {"left": {"img": str(paths[0]), "disp": [-high, -min_disparity],
                               "nodata": "NaN"},
                      "right": {"img": str(paths[1]), "nodata": "NaN"}},
            "pipeline": {
                "matching_cost": {"matching_cost_method": "census", "window_size": 5,
                                  "subpix": 1},
                "optimization": {"optimization_method": "sgm", "overcounting": False,
                                 "penalty": {"P1": 8, "P2": 32, "p2_method": "constant",
                                             "penalty_method": "sgm_penalty"}},
                "disparity": {"disparity_method": "wta", "invalid_disparity": "NaN"},
                "refinement": {"refinement_method": "vfit"},
                "filter": {"filter_method": "median", "filter_size": 3},
                "validation": validation,
            },
        }
        pandora.import_plugin()
        machine = PandoraMachine()
        cfg = check_conf(cfg, machine)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            image_left = create_dataset_from_inputs(input_config=cfg["input"]["left"])
            image_right = create_dataset_from_inputs(input_config=cfg["input"]["right"])
        start = time.perf_counter()
        result, _ = pandora.run(machine, image_left, image_right, cfg)
        seconds = time.perf_counter() - start
    disparity = -np.asarray(result["disparity_map"].data, dtype=np.float32)
    invalid = (np.asarray(result["validity_mask"].data).astype(np.int64)
               & int(Criteria.PANDORA_MSK_PIXEL_INVALID)) != 0
    disparity[invalid] = np.nan
    return disparity, seconds
