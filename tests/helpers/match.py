"""Synthetic rectified pairs with known disparity for the `match` tests."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from tests.helpers.texture import texture as band_limited


def texture(height: int, width: int, seed: int = 0) -> np.ndarray:
    """A band-limited random texture (two scales), float64, about zero mean."""
    return band_limited(
        (height, width), np.random.default_rng(seed), blurs=(1.2, 4.0), weights=(1.0, 0.5))


def smooth_disparity(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth disparity field (pixels): 3 … 9 px, gentle slopes."""
    return 6.0 + 2.5 * np.sin(x / 25.0) * np.cos(y / 30.0) + 0.005 * x


def textured_pair(height: int = 96, width: int = 128, *, seed: int = 0, gain: float = 1.3,
                  offset: float = 0.2, noise: float = 0.0,
                  disparity=smooth_disparity) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rectified pair whose right image is the left texture displaced by ``disparity``.

    ``x_right = x_left − d(x_left, y)``: the right image at column x shows the texture at
    the column x_l solving x_l − d(x_l, y) = x (fixed-point iteration), resampled with
    cubic splines; the right image also has a gain and offset (radiometric model).

    Returns
    -------
    left, right : (height, width) float32
    truth : (height, width) float64
        Disparity of every left pixel.
    """
    pad = 24
    tex = texture(height + 2 * pad, width + 2 * pad, seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    left = ndimage.map_coordinates(tex, [yy + pad, xx + pad], order=3)
    x_left = xx.copy()
    for _ in range(40):
        x_left = xx + disparity(x_left, yy)
    right = gain * ndimage.map_coordinates(tex, [yy + pad, x_left + pad], order=3) + offset
    if noise:
        rng = np.random.default_rng(seed + 1)
        left = left + rng.normal(scale=noise, size=left.shape)
        right = right + rng.normal(scale=noise, size=right.shape)
    return left.astype(np.float32), right.astype(np.float32), disparity(xx, yy)
