"""Stereo pairs with truth shared by the stereo benchmarks, and the OpenCV reference.

- :func:`synthetic_pair`: the synthetic scene's target/partner pair, rectified by
  ``demtool.rectify``, with the truth disparity from ``demtool.synth.truth_disparity``.
- :func:`middlebury_pair`: a Middlebury pair from ``../shared/data/middlebury`` (read
  its README; © Middlebury College, Scharstein & Szeliski 2002, 2003).
- :func:`opencv_sgbm`: OpenCV StereoSGBM MODE_HH, the reference to beat.

Disparity convention everywhere: x_right = x_left − d, NaN = invalid.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MIDDLEBURY = ROOT.parent / "shared" / "data" / "middlebury"

# name: (left, right, truth, truth scale, disparity count, non-occlusion mask or None)
MIDDLEBURY_PAIRS = {
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 16, None),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 32, None),
    "cones": ("im2.png", "im6.png", "disp2.png", 4, 64, "derived/nonocc_lrcheck.png"),
    "teddy": ("im2.png", "im6.png", "disp2.png", 4, 64, "derived/nonocc_lrcheck.png"),
}


class StereoPair(NamedTuple):
    """A pair with truth: images (H, W) float32, truth disparity (H, W) px, masks."""

    left: np.ndarray
    right: np.ndarray
    truth: np.ndarray
    masks: dict[str, np.ndarray]  # "visible" (synthetic) or "all" and "nonocc" (Middlebury)
    min_disparity: int
    num_disparities: int
    seeds: tuple[np.ndarray, np.ndarray] | None  # rectified inlier matches, if known

    @property
    def evaluation_mask(self) -> np.ndarray:
        """The non-occluded pixels with truth (the mask the issues' targets use)."""
        for key in ("visible", "nonocc", "all"):
            if key in self.masks:
                return self.masks[key]
        raise KeyError("no mask")


def synthetic_pair(quick: bool) -> StereoPair:
    """The synthetic target/partner pair, rectified, with its truth and disparity range."""
    from demtool.homography import warp_to_rectified
    from demtool.rectify import rectify_pair
    from demtool.synth import SceneParams, make_scene, truth_disparity

    params = (SceneParams(seed=0, dem_size=256, image_size=256, n_views=2, crater_count=20,
                          crater_max_diameter_m=50.0) if quick else SceneParams(n_views=2))
    scene = make_scene(params)
    left, right = scene.images[scene.target], scene.images[scene.partner]
    rect = rectify_pair(left, right)
    size = rect.size_rect
    left_rect = warp_to_rectified(left, rect.H_left, size)
    right_rect = warp_to_rectified(right, rect.H_right, size)
    truth = truth_disparity(scene, rect.H_left, rect.H_right, (int(size[1]), int(size[0])))
    low, high = rect.disparity_range
    min_disparity = int(math.floor(low))
    count = int(math.ceil(high)) - min_disparity + 1
    visible = truth.visible & np.isfinite(left_rect) & np.isfinite(right_rect)
    return StereoPair(left_rect, right_rect, truth.disparity, {"visible": visible},
                      min_disparity, count, (rect.points_left_rect, rect.points_right_rect))


def middlebury_pair(name: str) -> StereoPair:
    """A Middlebury pair (grey), its truth (px) and masks ("all" with truth, "nonocc")."""
    from demtool import io as dio

    folder = MIDDLEBURY / name
    left_name, right_name, truth_name, scale, count, mask_name = MIDDLEBURY_PAIRS[name]
    left = dio.read_image(folder / left_name).data
    right = dio.read_image(folder / right_name).data
    raw = dio.read_image(folder / truth_name).data
    masks = {"all": raw > 0}
    if mask_name is not None:
        masks["nonocc"] = masks["all"] & (dio.read_image(folder / mask_name).data > 127)
    return StereoPair(left, right, (raw / scale).astype(np.float32), masks, 0, count, None)


def opencv_sgbm(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int,
                block_size: int = 5) -> tuple[np.ndarray, float]:
    """OpenCV StereoSGBM MODE_HH with OpenCV's recommended penalties.

    Returns the disparity (NaN = invalid) and the compute time in seconds.
    """
    import cv2

    from demtool.features import to_uint8

    count = int(math.ceil(num_disparities / 16) * 16)
    matcher = cv2.StereoSGBM_create(minDisparity=int(min_disparity), numDisparities=count,
                                    blockSize=block_size, P1=8 * block_size**2,
                                    P2=32 * block_size**2, disp12MaxDiff=1,
                                    uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
                                    mode=cv2.STEREO_SGBM_MODE_HH)
    start = time.perf_counter()
    raw = matcher.compute(to_uint8(left)[0], to_uint8(right)[0])
    seconds = time.perf_counter() - start
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw <= (min_disparity - 1) * 16] = np.nan
    disparity[~(np.isfinite(left) & np.isfinite(right))] = np.nan
    return disparity, seconds
