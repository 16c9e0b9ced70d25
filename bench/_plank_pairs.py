"""Generated weak-texture "plank" pairs with exact truth (issue 26).

A large, smooth, slanted plank with faint texture stands in front of a textured,
gently sloping background, the situation where mutual information fails on the
Middlebury 2006 pairs: the plank covers a third or more of the image, its texture is
near the noise, and the search range is the user's ``0 … ndisp``, much wider than the
disparities present.  Rendered in layers (the plank always in front), so occlusions
and the truth are exact: the left pixels the plank hides in the right view are
occluded, and the right image's background is sampled at the background's own
surface coordinates.

Disparity convention: ``x_right = x_left − d``; the truth is in the left frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from _stereo_pairs import WEAK_SPECTRAL_EXPONENT, StereoPair


class Plank(NamedTuple):
    """Recipe of a plank pair (grey levels: DN; disparities at full size, px)."""

    seed: int
    dtype: str  # "float32" or "uint8" (rounded)
    plank_texture: float  # σ of the plank's fractal albedo, DN
    background_texture: float  # σ of the background's albedo, DN
    noise: float  # σ of the Gaussian noise of each image, DN
    plank_disparity: tuple[float, float]  # at the plank's left and right edges, px
    background_disparity: float  # mean background disparity, px
    num_disparities: int  # the user's range 0 … ndisp − 1
    gain: float = 1.0  # right = gain · left + offset
    offset: float = 0.0
    scale: float = 1.0  # image size 360 × 480 and disparities times this




#: Plank pairs of the benchmark: plank texture σ 1–3 DN against noise σ 1–2 DN, 8-bit and
#: float, with and without a gain; at half size (scale 0.5, 180 × 240) and full size.
PLANK_PAIRS = {
    "plank1": Plank(21, "uint8", 1.0, 20.0, 1.0, (90.0, 110.0), 15.0, 128, scale=0.5),
    "plank2": Plank(12, "float32", 1.5, 15.0, 1.5, (95.0, 105.0), 30.0, 128, 1.1, 8.0,
                    scale=0.5),
    "plank3": Plank(11, "uint8", 2.0, 25.0, 1.0, (70.0, 90.0), 20.0, 128),
    "plank4": Plank(13, "uint8", 3.0, 20.0, 2.0, (40.0, 60.0), 12.0, 96, 0.9, -5.0),
    "plank5": Plank(21, "uint8", 1.0, 20.0, 1.0, (90.0, 110.0), 15.0, 128),
}


def _albedo(rng: np.random.Generator, shape: tuple[int, int], sigma: float,
            beta: float) -> np.ndarray:
    """A fractal albedo pattern of standard deviation ``sigma`` DN (mean 0)."""
    from demtool.synth.terrain import fractal_surface

    size = 1 << int(np.ceil(np.log2(max(shape))))
    surface = fractal_surface(size, 1.0, spectral_exponent=beta, rms_m=1.0,
                              rng=rng)[:shape[0], :shape[1]]
    return sigma * (surface - surface.mean()) / surface.std()


def plank_pair(recipe: Plank, quick: bool = False) -> StereoPair:
    """A plank pair: images (float32 DN), truth (px), masks "all" and "nonocc".

    The background's disparity is ``background_disparity`` plus a gentle slope; the
    plank (about 55 % of the width, 70 % of the height) is a plane whose disparity
    runs linearly from ``plank_disparity[0]`` to ``[1]`` across it.  Size, disparities
    and range are scaled by ``recipe.scale``, and halved again with ``quick``.
    """
    scale = recipe.scale * (0.5 if quick else 1.0)
    height, width = int(360 * scale), int(480 * scale)
    count = int(round(recipe.num_disparities * scale))
    rng = np.random.default_rng(recipe.seed)
    margin = int(recipe.num_disparities * scale) + 8
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    # background: a gently sloping plane, textured strongly (β 2: more fine detail)
    d_back = scale * (recipe.background_disparity + 6.0 * (rows / height - 0.5)
                      + 4.0 * (cols / width - 0.5))
    back = _albedo(rng, (height, width + 2 * margin), recipe.background_texture, 2.0)
    plank = _albedo(rng, (height, width + 2 * margin), recipe.plank_texture,
                    WEAK_SPECTRAL_EXPONENT)
    x0, x1 = int(0.3 * width), int(0.85 * width)
    y0, y1 = int(0.15 * height), int(0.85 * height)
    d0, d1 = (scale * d for d in recipe.plank_disparity)
    d_plank = d0 + (d1 - d0) * (cols - x0) / (x1 - x0) + scale * 2.0 * (rows - y0) / height
    in_plank = (cols >= x0) & (cols < x1) & (rows >= y0) & (rows < y1)
    truth = np.where(in_plank, d_plank, d_back)
    grid = np.arange(width + 2 * margin, dtype=np.float64) - margin  # texture x of left x
    level = 110.0 if recipe.dtype == "uint8" else 400.0
    left = level + np.where(in_plank, plank[:, margin:margin + width],
                            back[:, margin:margin + width])
    right = np.empty((height, width))
    shows_plank = np.zeros((height, width), dtype=bool)
    xr = np.arange(width, dtype=np.float64)
    for row in range(height):
        # background: the left x with x − d_back(x) = xr (d_back is linear in x)
        slope = scale * 4.0 / width
        xb = (xr + d_back[row, 0]) / (1.0 - slope)
        value = np.interp(xb, grid, back[row])
        if y0 <= row < y1:  # the plank: x − d_plank(x) = xr, linear as well
            k = (d1 - d0) / (x1 - x0)
            xp = (xr + d_plank[row, x0] - k * x0) / (1.0 - k)
            on = (xp >= x0) & (xp < x1)
            value = np.where(on, np.interp(xp, grid, plank[row]), value)
            shows_plank[row] = on
        right[row] = value
    right = recipe.gain * (level + right) + recipe.offset
    left = left + rng.normal(0.0, recipe.noise, left.shape)
    right = right + rng.normal(0.0, recipe.noise, right.shape)
    if recipe.dtype == "uint8":
        left, right = (np.clip(np.rint(a), 0, 255) for a in (left, right))
    match = np.rint(cols - truth).astype(np.int64)
    inside = (match >= 0) & (match < width)
    hidden = np.take_along_axis(shows_plank, np.clip(match, 0, width - 1), axis=1)
    nonocc = inside & (in_plank | ~hidden)
    return StereoPair(left.astype(np.float32), right.astype(np.float32),
                      truth.astype(np.float32), {"all": inside, "nonocc": nonocc}, 0,
                      count, None)
