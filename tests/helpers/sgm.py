"""Synthetic rectified pairs with known disparity for the sgm tests (and benchmarks).

Disparity convention: ``x_right = x_left − d``; the truth is in the left image's frame.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from tests.helpers.texture import texture as band_limited


def texture(rng: np.random.Generator, shape: tuple[int, int], *, blur: float = 1.0,
            sigma: float = 40.0, mean: float = 1000.0) -> np.ndarray:
    """Band-limited random texture (Gaussian-smoothed white noise), float64 grey levels."""
    return band_limited(shape, rng, blurs=(blur,), mode="wrap", centred=True, sigma=sigma,
                        mean=mean)


def smooth_disparity_pair(height: int = 96, width: int = 128, *, seed: int = 1,
                          offset: float = 0.0, amplitude: float = 4.0, noise: float = 2.0,
                          gain: float = 1.0, bias: float = 0.0, blur: float = 1.0,
                          sigma: float = 40.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured pair related by a smooth disparity field.

    The right image samples the texture at ``x_r + f(x_r, y)`` with
    ``f = offset + amplitude·sin(x/30) + 3·y/H``; the left image is the texture
    itself, so the left-frame truth solves ``d(x) = f(x − d(x))``.  The right image
    has gain ``gain`` and offset ``bias``; both get Gaussian noise ``noise``.

    Returns
    -------
    left, right : (H, W) float32 grey levels (about 1000 ± ``sigma``)
    truth : (H, W) float32 disparity of the left pixels, px
    """
    rng = np.random.default_rng(seed)
    margin = int(abs(offset) + amplitude + 8)
    base = texture(rng, (height, width + 2 * margin), blur=blur, sigma=sigma)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)

    def field(x, y):
        return offset + amplitude * np.sin(x / 30.0) + 3.0 * y / height

    truth = field(cols, rows)
    for _ in range(40):
        truth = field(cols - truth, rows)
    left = base[:, margin:margin + width]
    right = ndimage.map_coordinates(base, [rows, cols + margin + field(cols, rows)], order=3)
    right = gain * right + bias
    left = left + rng.normal(0.0, noise, left.shape)
    right = right + rng.normal(0.0, noise, right.shape)
    return left.astype(np.float32), right.astype(np.float32), truth.astype(np.float32)


def fractional_shift_pair(shift: float, height: int = 64, width: int = 128, *, seed: int = 3
                          ) -> tuple[np.ndarray, np.ndarray]:
    """A pair related by a constant fractional disparity ``shift`` (exact Fourier shift).

    The texture is periodic along x and band-limited, so the right image
    ``right(x) = left(x + shift)`` is exact (no interpolation error).
    """
    rng = np.random.default_rng(seed)
    left = texture(rng, (height, width), blur=1.2)
    spectrum = np.fft.fft(left, axis=1)
    frequencies = np.fft.fftfreq(width)
    right = np.real(np.fft.ifft(spectrum * np.exp(2j * np.pi * frequencies * shift), axis=1))
    return left.astype(np.float32), right.astype(np.float32)


def occlusion_pair(height: int = 96, width: int = 128, *, seed: int = 5, background: int = 4,
                   foreground: int = 14, box: tuple[int, int, int, int] = (30, 66, 56, 100),
                   noise: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A fronto-parallel box in front of a background plane, integer disparities.

    The box (rows ``box[0]:box[1]``, left columns ``box[2]:box[3]``) has disparity
    ``foreground``, the rest ``background``; the right image is composed so that the
    box hides the background strip of width ``foreground − background`` to the left
    of the box in the left image (occluded: no correct match exists there).

    Returns
    -------
    left, right : (H, W) float32
    truth : (H, W) float32 disparity of the left pixels
    occluded : (H, W) bool, left pixels hidden in the right image
    """
    rng = np.random.default_rng(seed)
    pad = foreground + 4
    back = texture(rng, (height, width + 2 * pad), blur=1.0)
    front = texture(rng, (height, width + 2 * pad), blur=1.0, mean=1100.0)
    r0, r1, c0, c1 = box
    rows, cols = np.mgrid[0:height, 0:width]
    in_box = (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
    left = np.where(in_box, front[:, pad:pad + width], back[:, pad:pad + width])
    # right pixel x_r shows the box where x_r + foreground falls inside it, else background
    box_in_right = (rows >= r0) & (rows < r1) & (cols + foreground >= c0) & (cols + foreground < c1)
    right = np.where(box_in_right, front[:, pad + foreground:pad + foreground + width],
                     back[:, pad + background:pad + background + width])
    truth = np.where(in_box, foreground, background).astype(np.float32)
    occluded = ((rows >= r0) & (rows < r1) & (cols >= c0 - (foreground - background))
                & (cols < c0))
    left = left + rng.normal(0.0, noise, left.shape)
    right = right + rng.normal(0.0, noise, right.shape)
    return left.astype(np.float32), right.astype(np.float32), truth, occluded


def error_rates(disparity: np.ndarray, truth: np.ndarray, mask: np.ndarray
                ) -> dict[str, float]:
    """Density, bad-1, bad-2 and mean absolute error of ``disparity`` on ``mask``.

    Bad rates and the MAE are over the valid (finite) pixels of the mask; density
    is the valid fraction of the mask.
    """
    valid = mask & np.isfinite(disparity)
    error = np.abs(disparity[valid] - truth[valid])
    return {"density": float(valid.sum() / max(mask.sum(), 1)),
            "bad1": float((error > 1).mean()) if error.size else float("nan"),
            "bad2": float((error > 2).mean()) if error.size else float("nan"),
            "mae": float(error.mean()) if error.size else float("nan")}


def write_rectified_pair(folder, left: np.ndarray, right: np.ndarray, truth: np.ndarray,
                         disparity_range: tuple[float, float]) -> None:
    """``left_rect.tif``, ``right_rect.tif``, ``truth.npy`` and an identity ``rectify.npz``
    whose ``disparity_range`` (what rectify estimated from its matches) is given."""
    from demtool import io as dio

    height, width = left.shape
    dio.write_raster(folder / "left_rect.tif", left, tags={"frame": "image:view_00_rect"})
    dio.write_raster(folder / "right_rect.tif", right, tags={"frame": "image:view_01_rect"})
    np.save(folder / "truth.npy", truth)
    points = np.array([[10.0, 10.0], [50.0, 40.0], [90.0, 70.0]])
    size = np.array([width, height])
    dio.write_npz(folder / "rectify.npz", "rectification", {
        "H_left": np.eye(3), "H_right": np.eye(3), "F": np.zeros((3, 3)),
        "size_left": size, "size_right": size, "size_rect": size,
        "points_left": points, "points_right": points,
        "points_left_rect": points, "points_right_rect": points,
        "disparity_range": np.array(disparity_range, dtype=float),
        "left_name": np.asarray("view_00"), "right_name": np.asarray("view_01")})


def plank_pair(height: int = 90, width: int = 120, *, seed: int = 21, plank: float = 1.0,
               background: float = 20.0, noise: float = 1.0, disparity: tuple = (22.0, 28.0),
               back_disparity: float = 4.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A faint-texture slanted plank in front of a textured background, 8-bit levels.

    The plank (columns 30–85 %, rows 15–85 % of the left image) is a plane whose
    disparity runs from ``disparity[0]`` to ``[1]`` across it, with albedo σ ``plank``
    grey levels against noise σ ``noise`` (weak texture: where mutual information
    fails); the background has σ ``background`` and the constant ``back_disparity``.
    Rendered in layers (the plank in front), so the truth is exact; a smaller copy of
    ``bench/_plank_pairs.py``.

    Returns
    -------
    left, right : (H, W) float32 grey levels (rounded to integers)
    truth : (H, W) float32 disparity of the left pixels, px
    """
    rng = np.random.default_rng(seed)
    margin = int(max(disparity)) + 8
    back = texture(rng, (height, width + 2 * margin), blur=1.0, sigma=background, mean=0.0)
    face = texture(rng, (height, width + 2 * margin), blur=2.0, sigma=plank, mean=0.0)
    x0, x1 = int(0.3 * width), int(0.85 * width)
    y0, y1 = int(0.15 * height), int(0.85 * height)
    cols = np.arange(width, dtype=np.float64)
    slope = (disparity[1] - disparity[0]) / (x1 - x0)
    d_plank = disparity[0] + slope * (cols - x0)
    grid = np.arange(width + 2 * margin, dtype=np.float64) - margin
    left = np.empty((height, width))
    right = np.empty((height, width))
    truth = np.full((height, width), back_disparity)
    for row in range(height):
        left[row] = np.interp(cols, grid, back[row])
        right[row] = np.interp(cols + back_disparity, grid, back[row])
        if y0 <= row < y1:
            left[row, x0:x1] = np.interp(cols[x0:x1], grid, face[row])
            truth[row, x0:x1] = d_plank[x0:x1]
            # the right pixel xr shows the plank point x with x − d_plank(x) = xr
            xp = (cols + disparity[0] - slope * x0) / (1.0 - slope)
            on = (xp >= x0) & (xp < x1)
            right[row, on] = np.interp(xp[on], grid, face[row])
    left = np.clip(np.rint(110.0 + left + rng.normal(0.0, noise, left.shape)), 0, 255)
    right = np.clip(np.rint(110.0 + right + rng.normal(0.0, noise, right.shape)), 0, 255)
    return left.astype(np.float32), right.astype(np.float32), truth.astype(np.float32)


def reference_aggregation(cost, guide, paths: int, kappa: float, p1: int, p2: int):
    """S = Σ_r L_r (Hirschmüller 2008 eq. 13–14) over the 8 or 16 directions, by plain
    loops (int64, no sentinels, P2 adapted to the guide's steps as
    :func:`demtool.sgm.aggregate.adapted_p2_table`): the reference of the vectorised
    kernel's tests."""
    from demtool.sgm.aggregate import adapted_p2_table

    p2_of_step = adapted_p2_table(p1, p2, kappa)
    height, width, count = cost.shape

    def path(dy, dx):
        out = np.zeros(cost.shape, dtype=np.int64)
        rows = range(height) if dy >= 0 else range(height - 1, -1, -1)
        cols = list(range(width)) if dx >= 0 else list(range(width - 1, -1, -1))
        for y in rows:
            for x in cols:
                yp, xp = y - dy, x - dx
                if not (0 <= yp < height and 0 <= xp < width):
                    out[y, x] = cost[y, x]  # the path starts here
                    continue
                prev = out[yp, xp]
                low = prev.min()
                penalty = p2_of_step[abs(int(guide[y, x]) - int(guide[yp, xp]))]
                for k in range(count):
                    step = min(prev[k - 1] if k > 0 else 10**9,
                               prev[k + 1] if k + 1 < count else 10**9) + p1
                    out[y, x, k] = cost[y, x, k] + min(prev[k], step, low + penalty) - low
        return out

    directions = [(0, 1), (1, 0), (1, 1), (1, -1)]
    if paths == 16:
        directions += [(1, 2), (1, -2), (2, 1), (2, -1)]
    directions += [(-dy, -dx) for dy, dx in directions]
    return sum(path(dy, dx) for dy, dx in directions)


def count_sgm_tiles(monkeypatch, *, fail_at: int | None = None) -> list[int]:
    """Record the index of every sgm tile computed from now on (the list returned),
    raising ``RuntimeError("worker lost")`` in tile ``fail_at``; each call patches the
    true :meth:`SgmTileJob.compute` again (not an earlier patch)."""
    from demtool.sgm import tiled as tiled_sgm

    original = tiled_sgm.SgmTileJob.__dict__["compute"]
    original = getattr(original, "__wrapped_tile_compute__", original)
    calls: list[int] = []

    def counted(self, tile, threads):
        calls.append(tile.index)
        if tile.index == fail_at:
            raise RuntimeError("worker lost")
        return original(self, tile, threads)

    counted.__wrapped_tile_compute__ = original
    monkeypatch.setattr(tiled_sgm.SgmTileJob, "compute", counted)
    return calls


def write_tiling_pair(folder) -> np.ndarray:
    """The tiling tests' 160 × 200 smooth-disparity pair (disparities −4 … 7 px) written
    as ``left.tif`` / ``right.tif`` in ``folder``; returns the truth."""
    from demtool import io as dio

    left, right, truth = smooth_disparity_pair(160, 200, seed=4, offset=1.0)
    dio.write_raster(folder / "left.tif", left, tags={"frame": "image:left_rect"})
    dio.write_raster(folder / "right.tif", right, tags={"frame": "image:right_rect"})
    return truth
