"""Shadow masks for shape from shading: cast shadows from a DEM, dark pixels of an image.

In a shadow the image carries no shading information, so the intensity term of the
SfS energy is dropped there and the surface follows the coarse DEM (Grumpe & Wöhler
2014 exclude shadowed pixels the same way).  Directions use the grid frame of
:mod:`demtool.refine.shading` (x image right, y image up, z toward the camera).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from demtool.refine.rowwork import on_row_blocks
from demtool.refine.shading import Illumination, cosine, slopes
from demtool.tiling.rows import on_row_parts


@nb.njit(cache=True, inline="always")
def _bilinear(dem: np.ndarray, row: float, col: float) -> float:
    height, width = dem.shape
    r0 = min(max(int(np.floor(row)), 0), height - 2)
    c0 = min(max(int(np.floor(col)), 0), width - 2)
    fr = row - r0
    fc = col - c0
    top = dem[r0, c0] * (1.0 - fc) + dem[r0, c0 + 1] * fc
    bottom = dem[r0 + 1, c0] * (1.0 - fc) + dem[r0 + 1, c0 + 1] * fc
    return top * (1.0 - fr) + bottom * fr


def _march_toward_sun(dem: np.ndarray, step_row: float, step_col: float, rise: float,
                      z_max: float, candidates: np.ndarray) -> np.ndarray:
    """Per candidate pixel, step toward the sun; shadowed if the terrain rises above the
    ray.  (H, W) bool; rows on every core (:func:`demtool.tiling.rows.on_row_parts`)."""
    shadow = np.zeros(dem.shape, dtype=np.bool_)
    on_row_parts(lambda start, stop: _march_rows(dem, step_row, step_col, rise, z_max,
                                                 candidates, shadow, start, stop),
                 dem.shape[0])
    return shadow


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _march_rows(dem, step_row, step_col, rise, z_max, candidates, shadow, start,
                stop):  # pragma: no cover - compiled
    height, width = dem.shape
    for r in range(start, stop):
        for c in range(width):
            if not candidates[r, c]:
                continue
            ray = dem[r, c]
            row = float(r)
            col = float(c)
            while True:
                row += step_row
                col += step_col
                ray += rise
                if ray > z_max or row < 0.0 or col < 0.0 or row > height - 1 \
                        or col > width - 1:
                    break
                if _bilinear(dem, row, col) > ray:
                    shadow[r, c] = True
                    break


def _dilate_cross(mask: np.ndarray, out: np.ndarray) -> None:
    """One binary dilation by the 3 × 3 cross (4-neighbours), outside the grid False:
    ``scipy.ndimage.binary_dilation(mask)`` with its default structure, rows on every
    core."""
    on_row_parts(lambda start, stop: _dilate_cross_rows(mask, out, start, stop),
                 mask.shape[0])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _dilate_cross_rows(mask, out, start, stop):  # pragma: no cover - compiled
    height, width = mask.shape
    for r in range(start, stop):
        for c in range(width):
            out[r, c] = (mask[r, c] or (r > 0 and mask[r - 1, c])
                         or (r + 1 < height and mask[r + 1, c])
                         or (c > 0 and mask[r, c - 1]) or (c + 1 < width and mask[r, c + 1]))


def dilate(mask: np.ndarray, iterations: int) -> np.ndarray:
    """``mask`` grown by ``iterations`` pixels along rows and columns (the 4-neighbour
    cross applied ``iterations`` times; ``scipy.ndimage.binary_dilation(mask,
    iterations=iterations)``, rows on every core)."""
    current = np.ascontiguousarray(mask, dtype=np.bool_)
    for _ in range(int(iterations)):
        grown = np.empty_like(current)
        _dilate_cross(current, grown)
        current = grown
    return current


def cast_shadows(dem: np.ndarray, spacing: tuple[float, float],
                 illumination: Illumination, candidates: np.ndarray | None = None
                 ) -> np.ndarray:
    """Pixels in the cast or attached shadow of a DEM under a directional sun.

    Marches from each pixel toward the sun in steps of at most one pixel, bilinearly
    sampling the DEM, until the ray rises above the DEM's maximum or leaves the grid
    (terrain outside the grid casts no shadow).  Pixels whose own surface faces away
    from the sun (μ0 ≤ 0, attached shadow) are included.

    Parameters
    ----------
    dem : (H, W) float
        Heights, metres, finite.
    spacing : (dx, dy)
        Pixel spacing along x (columns) and y (rows), metres.
    illumination : Illumination
        Sun direction in the grid frame (z > 0).
    candidates : (H, W) bool, optional
        Only these pixels are ray-marched (default: all); the others are False unless
        in attached shadow.

    Returns
    -------
    shadow : (H, W) bool
        True where the pixel does not see the sun.
    """
    z, z_max = _as_float64(dem)
    sx, sy, sz = (float(v) for v in illumination.sun)
    horizontal = np.hypot(sx, sy)
    if horizontal < 1e-9 or z.shape[0] < 2 or z.shape[1] < 2:
        attached = np.zeros(z.shape, dtype=np.bool_)
        _or_attached(z, spacing, illumination.sun, attached)
        return attached
    # displacement toward the sun per metre of horizontal travel, in pixels
    per_metre_col = sx / horizontal / spacing[0]
    per_metre_row = -sy / horizontal / spacing[1]  # y up = rows decreasing
    metres_per_step = 1.0 / max(abs(per_metre_col), abs(per_metre_row))
    rise = sz / horizontal * metres_per_step
    march = np.ones(z.shape, dtype=bool) if candidates is None else \
        np.ascontiguousarray(candidates, dtype=bool)
    shadow = _march_toward_sun(z, per_metre_row * metres_per_step,
                               per_metre_col * metres_per_step, rise, z_max, march)
    _or_attached(z, spacing, illumination.sun, shadow)
    return shadow


def _as_float64(dem: np.ndarray) -> tuple[np.ndarray, float]:
    """``dem`` as a C-ordered float64 array and its maximum (the copy and the maximum by
    row parts on every core; a maximum of the parts' maxima is the same number)."""
    dem = np.asarray(dem)
    if dem.ndim != 2 or dem.shape[0] < 2 or dem.size == 0:
        z = np.ascontiguousarray(dem, dtype=np.float64)
        return z, float(z.max()) if z.size else float("nan")
    z = dem if dem.dtype == np.float64 and dem.flags.c_contiguous else \
        np.empty(dem.shape, dtype=np.float64)
    maxima = np.full(dem.shape[0], -np.inf)

    def part(start: int, stop: int) -> None:
        if z is not dem:
            z[start:stop] = dem[start:stop]
        maxima[start] = z[start:stop].max()

    on_row_blocks(part, *dem.shape)
    return z, float(maxima.max())


def _or_attached(z: np.ndarray, spacing: tuple[float, float], sun: np.ndarray,
                 shadow: np.ndarray) -> None:
    """``shadow |= `` the attached shadow of ``z`` (μ0 ≤ 0: the surface faces away from
    the sun): :func:`~demtool.refine.shading.slopes` and
    :func:`~demtool.refine.shading.cosine`, evaluated on row parts on every core (each
    part with the rows next to it, mirrored at the grid's edges as ``slopes`` does; the
    same arithmetic per pixel, so the same bits)."""
    height = z.shape[0]

    def part(start: int, stop: int) -> None:
        top, bottom = max(start - 1, 0), min(stop + 1, height)
        p, q = slopes(z[top:bottom], spacing)
        inner = slice(start - top, stop - top)  # the halo rows' own slopes are dropped
        shadow[start:stop] |= cosine(p[inner], q[inner], sun) <= 0.0

    on_row_blocks(part, height, z.shape[1])


def dark_pixels(image: np.ndarray, threshold: float, valid: np.ndarray | None = None,
                median: float | None = None) -> np.ndarray:
    """Pixels darker than ``threshold`` × the median of the valid image.

    Parameters
    ----------
    image : (H, W) float
        Image values (any linear unit: DN, I/F); NaN = no data.
    threshold : float
        Fraction of the median; 0 disables the test.
    valid : (H, W) bool, optional
        Pixels to consider (default: finite ones).
    median : float, optional
        The median of the valid image, if already known.

    Returns
    -------
    (H, W) bool
        True for dark (shadowed) pixels.
    """
    values = np.asarray(image, dtype=np.float32)
    if threshold > 0 and median is not None and values.ndim == 2:
        # no selection to make: the test on row parts on every core (without a valid
        # pixel it is False everywhere, as below)
        level = threshold * median
        dark = np.empty(values.shape, dtype=bool)

        def part(start: int, stop: int) -> None:
            rows = values[start:stop]
            usable = np.isfinite(rows) if valid is None else \
                np.broadcast_to(valid, values.shape)[start:stop] & np.isfinite(rows)
            np.logical_and(usable, rows < level, out=dark[start:stop])

        on_row_blocks(part, *values.shape)
        return dark
    valid = np.isfinite(values) if valid is None else valid & np.isfinite(values)
    if threshold <= 0 or not valid.any():
        return np.zeros(values.shape, dtype=bool)
    level = threshold * (float(np.median(values[valid])) if median is None else median)
    return valid & (values < level)


def shadow_mask(dem: np.ndarray, image: np.ndarray, spacing: tuple[float, float],
                illumination: Illumination, *, threshold: float = 0.0,
                use_dem: bool = True, dim_fraction: float = 0.2,
                dilate_px: int = 1, median: float | None = None,
                image_masks: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Combined shadow mask: dark image pixels, and the DEM's shadows where the image is dim.

    The image decides: a pixel darker than ``threshold`` × the median is shadow.  The
    cast and attached shadows of the current DEM add the pixels that are dim (below
    ``dim_fraction`` × the median) but above the threshold — penumbrae and the dark
    fringes of shadows.  Where the image is bright the DEM's shadow is not trusted: a
    lit pixel in a predicted shadow means the DEM is wrong there, which is what the
    shading has to correct (a noisy coarse DEM under a low sun "shadows" half the grid).

    Parameters
    ----------
    dem : (H, W) float
        Current heights, metres.
    image : (H, W) float
        The image on the same grid; NaN = no data.
    spacing : (dx, dy)
        Pixel spacing, metres.
    illumination : Illumination
        Sun direction.
    threshold : float
        Dark-pixel threshold (fraction of the median); 0 disables it.
    use_dem : bool
        Include the cast and attached shadows of ``dem`` (where the image is dim).
    dim_fraction : float
        Fraction of the median image below which a DEM shadow is believed.
    dilate_px : int
        Grow the mask by this many pixels (penumbra, DEM errors at shadow edges).
    median : float, optional
        The median of the valid image, if already known (saves a selection).
    image_masks : (dark, dim), optional
        :func:`image_shadows` of ``image`` with the same ``threshold``, ``dim_fraction``
        and median, if already known (a solver re-estimating the shadows of a changing
        DEM computes them once).

    Returns
    -------
    (H, W) bool
        True where the intensity term must be dropped.
    """
    dark, dim = image_masks if image_masks is not None else image_shadows(
        image, threshold, dim_fraction=dim_fraction, median=median)
    if use_dem:
        shadow = dark | (cast_shadows(dem, spacing, illumination, candidates=dim) & dim)
    else:
        shadow = dark.copy()
    if dilate_px > 0 and shadow.any():
        shadow = dilate(shadow, int(dilate_px))
    return shadow


def image_shadows(image: np.ndarray, threshold: float, *, dim_fraction: float = 0.2,
                  median: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The image's masks of :func:`shadow_mask`, which do not change with the DEM: the
    dark pixels (below ``threshold`` × the median) and the dim ones (below
    ``dim_fraction`` × the median), (H, W) bool each (:func:`dark_pixels`)."""
    values = np.asarray(image, dtype=np.float32)
    if median is None:
        finite = np.isfinite(values)
        median = float(np.median(values[finite])) if finite.any() else 0.0
    return (dark_pixels(values, threshold, median=median),
            dark_pixels(values, dim_fraction, median=median))
