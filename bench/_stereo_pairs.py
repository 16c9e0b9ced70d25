"""Stereo pairs with truth shared by the stereo benchmarks, and the OpenCV reference.

- :func:`synthetic_pair`: the synthetic scene's target/partner pair, rectified by
  ``demtool.rectify.core``, with the truth disparity from ``demtool.synth.truth_disparity``.
- :func:`middlebury_pair`: a Middlebury pair from ``../shared/data/middlebury`` (read
  its README; © Middlebury College, Scharstein & Szeliski 2002, 2003; Hirschmüller &
  Scharstein 2007 for cloth3).
- :func:`weak_texture_pair`: a generated planetary-like pair (weak fractal texture,
  noise, gain and offset, smooth or stepped disparity) with exact truth and occlusions;
  :data:`WEAK_TEXTURE_PAIRS` is the benchmark's family of them.
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

# name: (left, right, truth, truth scale, disparity count, non-occlusion mask: a file, the
# right truth (checked left-right within 1 px on the fly, as the derived files were made),
# or None)
MIDDLEBURY_PAIRS = {
    "tsukuba": ("im3.png", "im4.png", "disp3.pgm", 16, 16, None),
    "venus": ("im2.png", "im6.png", "disp2.pgm", 8, 32, None),
    "cones": ("im2.png", "im6.png", "disp2.png", 4, 64, "derived/nonocc_lrcheck.png"),
    "teddy": ("im2.png", "im6.png", "disp2.png", 4, 64, "derived/nonocc_lrcheck.png"),
    "cloth3": ("view1.png", "view5.png", "disp1.png", 2, 96, "disp5.png"),
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


def synthetic_pair(quick: bool, params=None) -> StereoPair:
    """The synthetic target/partner pair, rectified, with its truth and disparity range.

    ``params`` (a :class:`demtool.synth.SceneParams`) renders another scene; else the
    default scene, or a 256² one when ``quick``.
    """
    from demtool.imaging.homography import warp_to_rectified
    from demtool.rectify.core import rectify_pair
    from demtool.synth import SceneParams, make_scene, truth_disparity

    if params is None:
        params = (SceneParams(seed=0, dem_size=256, image_size=256, n_views=2,
                              crater_count=20, crater_max_diameter_m=50.0) if quick
                  else SceneParams(n_views=2))
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
    truth = (raw / scale).astype(np.float32)
    masks = {"all": raw > 0}
    if mask_name is not None and mask_name.startswith("derived/"):
        masks["nonocc"] = masks["all"] & (dio.read_image(folder / mask_name).data > 127)
    elif mask_name is not None:  # the right view's truth: left-right check within 1 px
        masks["nonocc"] = masks["all"] & lr_consistent(
            truth, (dio.read_image(folder / mask_name).data / scale).astype(np.float32))
    return StereoPair(left, right, truth, masks, 0, count, None)


def lr_consistent(truth_left: np.ndarray, truth_right: np.ndarray, tolerance: float = 1.0
                  ) -> np.ndarray:
    """(H, W) bool: left pixels whose right-view truth at x − d agrees within ``tolerance``.

    The stand-in for a non-occlusion mask the data README describes (0 = no truth).
    """
    height, width = truth_left.shape
    cols = np.arange(width)[None, :] - np.rint(truth_left).astype(np.int64)
    inside = (cols >= 0) & (cols < width) & (truth_left > 0)
    other = np.take_along_axis(truth_right, np.clip(cols, 0, width - 1), axis=1)
    return inside & (other > 0) & (np.abs(other - truth_left) <= tolerance)


# ------------------------------------------------------------------ weak-texture pairs


class WeakTexture(NamedTuple):
    """Recipe of a generated weak-texture pair (grey levels: DN)."""

    seed: int
    dtype: str  # "float32" (not rounded, around 400 DN) or "uint8" (rounded, around 100)
    texture: float  # σ of the fractal albedo texture, DN
    noise: float  # σ of the Gaussian noise added to each image after the gain, DN
    gain: float  # right = gain · texture + offset
    offset: float  # DN
    field: str  # "smooth" or "stepped" disparity


#: The benchmark's family: several seeds, both dtypes, texture σ 3–8 DN, noise σ 1–4 DN,
#: gain 0.8–1.25 with an offset, smooth and stepped disparity fields.
WEAK_TEXTURE_PAIRS = {
    "weak1": WeakTexture(1, "float32", 5.0, 3.0, 1.20, 12.0, "smooth"),
    "weak2": WeakTexture(2, "uint8", 3.0, 1.0, 0.80, -6.0, "stepped"),
    "weak3": WeakTexture(3, "float32", 8.0, 4.0, 1.25, 25.0, "stepped"),
    "weak4": WeakTexture(4, "uint8", 4.0, 2.0, 0.90, 8.0, "smooth"),
    "weak5": WeakTexture(5, "float32", 6.0, 4.0, 1.10, -15.0, "stepped"),
    "weak6": WeakTexture(6, "uint8", 3.0, 2.0, 1.25, 5.0, "smooth"),
}
WEAK_SPECTRAL_EXPONENT = 2.3  # β of the texture's power spectrum P(k) ∝ k^-β
WEAK_DISPARITIES = 48  # search range 0 … 47


def _weak_field(kind: str, height: int, width: int) -> np.ndarray:
    """Left-frame truth disparity (H, W) px in 8 … 38: smooth, or smooth plus steps."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    d = (20.0 + 6.0 * np.sin(2 * np.pi * cols / width) * np.cos(2 * np.pi * rows / height)
         + 4.0 * rows / height)
    if kind == "stepped":
        disk = np.hypot(cols - 0.3 * width, rows - 0.4 * height) < 0.15 * min(height, width)
        box = ((np.abs(cols - 0.65 * width) < 0.12 * width)
               & (np.abs(rows - 0.65 * height) < 0.18 * height))
        d = d + 10.0 * disk - 8.0 * box + 5.0 * (cols > 0.85 * width)
    return d


def _render_right(texture_row, d_row, margin, oversample=16):
    """One right-image row by forward warping with a z-buffer (the larger d is nearer).

    The left pixel x shows the texture at ``x + margin``; it lands at x − d(x) in the
    right image.  Returns the right row and, per right pixel, the disparity it shows.
    """
    width = d_row.size
    x = np.arange(width * oversample) / oversample - 0.5 + 0.5 / oversample
    d = np.interp(x, np.arange(width), d_row)
    if np.any(np.abs(np.diff(d_row)) > 1.5):  # steps: nearest pixel's disparity, not a ramp
        d = d_row[np.clip(np.rint(x).astype(int), 0, width - 1)]
    xr = np.rint(x - d).astype(np.int64)
    inside = (xr >= 0) & (xr < width)
    shown = np.full(width, -np.inf)
    np.maximum.at(shown, xr[inside], d[inside])
    # the texture at the right pixel centre of the visible surface: xr + d
    hole = ~np.isfinite(shown)
    if hole.any():  # seen by the right view only: the background behind it
        idx = np.flatnonzero(~hole)
        nearest = idx[np.clip(np.searchsorted(idx, np.flatnonzero(hole)), 0, idx.size - 1)]
        previous = idx[np.clip(np.searchsorted(idx, np.flatnonzero(hole)) - 1, 0,
                               idx.size - 1)]
        shown[hole] = np.minimum(shown[nearest], shown[previous])
    positions = np.arange(width) + shown + margin
    values = np.interp(positions, np.arange(texture_row.size), texture_row)
    return values, shown


def weak_texture_pair(recipe: WeakTexture, quick: bool = False) -> StereoPair:
    """A generated planetary-like pair: weak fractal texture, noise, gain, exact truth.

    The albedo is a fractal (power spectrum ∝ k^-2.3, ``demtool.synth.terrain.
    fractal_surface``) scaled to σ = ``recipe.texture`` DN, so most of its variance is
    at low spatial frequencies and the fine detail matching relies on is near the
    noise.  The left image shows it directly; the right image is forward-warped by the
    left-frame disparity field with a z-buffer (the larger disparity is nearer), so
    stepped fields have true occlusions, then gets ``gain`` and ``offset``.  Both get
    Gaussian noise σ = ``recipe.noise``; "uint8" pairs are rounded to integer levels.
    Masks: "all" = the left pixels that land inside the right image, "nonocc" = those
    the right view sees.
    """
    from demtool.synth.terrain import fractal_surface

    height, width = (256, 320) if quick else (400, 560)
    rng = np.random.default_rng(recipe.seed)
    margin = 64
    surface = fractal_surface(1024, 1.0, spectral_exponent=WEAK_SPECTRAL_EXPONENT,
                              rms_m=1.0, rng=rng)[:height, :width + 2 * margin]
    level = 400.0 if recipe.dtype == "float32" else 100.0
    texture = level + recipe.texture * (surface - surface.mean()) / surface.std()
    truth = _weak_field(recipe.field, height, width)
    right = np.empty((height, width))
    shown = np.empty((height, width))
    for row in range(height):
        right[row], shown[row] = _render_right(texture[row], truth[row], margin)
    left = texture[:, margin:margin + width]
    right = recipe.gain * right + recipe.offset
    left = left + rng.normal(0.0, recipe.noise, left.shape)
    right = right + rng.normal(0.0, recipe.noise, right.shape)
    if recipe.dtype == "uint8":
        left, right = (np.clip(np.rint(a), 0, 255) for a in (left, right))
    cols = np.arange(width)[None, :] - np.rint(truth).astype(np.int64)
    inside = (cols >= 0) & (cols < width)
    seen = np.take_along_axis(shown, np.clip(cols, 0, width - 1), axis=1)
    nonocc = inside & (seen <= truth + 0.5)
    return StereoPair(left.astype(np.float32), right.astype(np.float32),
                      truth.astype(np.float32), {"all": inside, "nonocc": nonocc}, 0,
                      WEAK_DISPARITIES, None)


def opencv_sgbm(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int,
                block_size: int = 5) -> tuple[np.ndarray, float]:
    """OpenCV StereoSGBM MODE_HH with OpenCV's recommended penalties.

    Returns the disparity (NaN = invalid) and the compute time in seconds.
    """
    import cv2

    from demtool.imaging.features import to_uint8

    count = int(math.ceil(num_disparities / 16) * 16)
    valid = np.isfinite(left) & np.isfinite(right)
    matcher = cv2.StereoSGBM_create(minDisparity=int(min_disparity), numDisparities=count,
                                    blockSize=block_size, P1=8 * block_size**2,
                                    P2=32 * block_size**2, disp12MaxDiff=1,
                                    uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
                                    mode=cv2.STEREO_SGBM_MODE_HH)

    def eight_bit(image):  # 8-bit levels as they are; anything else stretched
        if valid.all() and np.all(image == np.rint(image)) and image.min() >= 0 \
                and image.max() <= 255:
            return image.astype(np.uint8)
        return to_uint8(image)[0]

    left8, right8 = eight_bit(left), eight_bit(right)
    start = time.perf_counter()
    raw = matcher.compute(left8, right8)
    seconds = time.perf_counter() - start
    disparity = raw.astype(np.float32) / 16.0
    disparity[raw <= (min_disparity - 1) * 16] = np.nan
    disparity[~valid] = np.nan
    return disparity, seconds


# ------------------------------------------------------------------------- scoring


SCORE_BORDER = 2  # px left out on every side (Pandora never answers there; issue 26)


def scored_masks(pair: StereoPair) -> dict[str, np.ndarray]:
    """The pair's masks with truth ("all", "nonocc"), the left ``ndisp`` columns excluded.

    A left pixel in the first max(0, min_disparity + num_disparities) columns may have
    its match outside the right image for part of the range; no matcher is scored
    there (the Middlebury evaluation's convention), nor in a :data:`SCORE_BORDER`-pixel
    border.  The synthetic pair's "visible" mask serves as both.
    """
    masks = dict(pair.masks)
    if "visible" in masks:
        masks = {"all": masks["visible"], "nonocc": masks["visible"]}
    masks.setdefault("nonocc", masks["all"])
    excluded = max(0, pair.min_disparity + pair.num_disparities)
    out = {}
    for key in ("all", "nonocc"):
        mask = masks[key].copy()
        mask[:, :excluded] = False
        mask[:SCORE_BORDER] = mask[-SCORE_BORDER:] = False
        mask[:, :SCORE_BORDER] = mask[:, -SCORE_BORDER:] = False
        out[key] = mask
    return out


def score(disparity: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """bad-1 / bad-2 with invalid pixels counted as bad, invalid fraction, MAE (fractions).

    Over the pixels of ``mask``: ``bad1`` and ``bad2`` are the fraction of pixels whose
    disparity is invalid (NaN) or off the truth by more than 1 / 2 px; ``invalid`` the
    fraction with no disparity; ``mae`` the mean absolute error of the valid ones, px.
    """
    total = max(int(mask.sum()), 1)
    valid = mask & np.isfinite(disparity)
    error = np.abs(disparity[valid] - truth[valid])
    n_invalid = total - int(valid.sum())
    return {"bad1": (int((error > 1).sum()) + n_invalid) / total,
            "bad2": (int((error > 2).sum()) + n_invalid) / total,
            "invalid": n_invalid / total,
            "mae": float(error.mean()) if error.size else math.nan}
