"""Large synthetic rectified pairs with exact truth for bench/scale.py (and the tiling tests).

The left image is a band-limited texture (Gaussian-smoothed white noise at σ = 1 and 3
px, σ = `contrast` grey levels around 1000, plus noise σ = 2); the right image samples it at
``x_r + f(x_r, y)`` with the smooth field ``f = 48 + 30·sin(2πx/W·1.5)·cos(2πy/H)``
(disparities 18 … 78 px, inside ``--min-disparity 0 --num-disparities 96``), so the
left-frame truth solves ``d(x) = f(x − d(x))``.  Built in row blocks so a 8192² pair
needs no more than a few hundred MB.  Convention: ``x_right = x_left − d``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

MARGIN = 96  # texture columns beyond the left image (right samples reach x + 78)


def field(x: np.ndarray, y: np.ndarray, height: int, width: int) -> np.ndarray:
    """The right-frame disparity field f(x_r, y), px."""
    return 48.0 + 30.0 * np.sin(2 * np.pi * 1.5 * x / width) * np.cos(2 * np.pi * y / height)


def make_pair(size: int, *, seed: int = 0, noise: float = 2.0, contrast: float = 6.0,
              block: int = 512
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(left, right, truth), each (size, size) float32; see the module docstring."""
    rng = np.random.default_rng(seed)
    height, width = size, size
    base = np.empty((height, width + MARGIN), dtype=np.float32)
    fine = ndimage.gaussian_filter(rng.normal(size=base.shape).astype(np.float32), 1.0,
                                   mode="wrap")
    base[:] = fine / fine.std()
    del fine
    coarse = ndimage.gaussian_filter(rng.normal(size=base.shape).astype(np.float32), 3.0,
                                     mode="wrap")
    base += coarse / coarse.std()
    del coarse
    base *= contrast
    base += 1000.0
    left = base[:, :width] + rng.normal(0.0, noise, (height, width)).astype(np.float32)
    right = np.empty((height, width), dtype=np.float32)
    truth = np.empty((height, width), dtype=np.float32)
    cols = np.arange(width, dtype=np.float64)[None, :]
    for r0 in range(0, height, block):
        r1 = min(height, r0 + block)
        rows = np.arange(r0, r1, dtype=np.float64)[:, None] + 0 * cols
        x = cols + 0 * rows
        d = field(x, rows, height, width)
        for _ in range(40):
            d = field(x - d, rows, height, width)
        truth[r0:r1] = d
        f = field(x, rows, height, width)
        right[r0:r1] = ndimage.map_coordinates(base, [rows, x + f], order=3, mode="nearest")
    right += rng.normal(0.0, noise, right.shape).astype(np.float32)
    return left, right, truth


def write_pair(folder: Path, size: int, *, seed: int = 0) -> tuple[Path, Path, Path]:
    """left_rect.tif, right_rect.tif and truth.npy of :func:`make_pair` in ``folder``."""
    from demtool import io as dio

    folder.mkdir(parents=True, exist_ok=True)
    left, right, truth = make_pair(size, seed=seed)
    paths = folder / "left_rect.tif", folder / "right_rect.tif", folder / "truth.npy"
    dio.write_raster(paths[0], left, tags={"frame": "image:left_rect"})
    dio.write_raster(paths[1], right, tags={"frame": "image:right_rect"})
    np.save(paths[2], truth)
    return paths
