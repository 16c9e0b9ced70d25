"""Shape from shading in overlapping tiles, each with its own sun and view directions.

Where the illumination geometry changes across a map (see :mod:`demtool.refine.geometry`)
the DEM is refined tile by tile, each tile under the directions at its centre, and the
tiles' heights are blended with weights that fall linearly to zero at each tile's
edges (a partition of unity over the overlaps, as s2p and ASP's ``parallel_sfs`` blend
their tiles), so no seam remains where two tiles' illuminations differ.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["overlapping_tiles", "refine_tiles", "tile_weight"]


def overlapping_tiles(shape: tuple[int, int], tile: int, overlap: int
                      ) -> list[tuple[int, int, int, int]]:
    """Windows ``(row0, row1, col0, col1)`` of about ``tile`` px overlapping by ``overlap``.

    The windows cover the grid; each is at least ``2 * overlap`` px on a side where the
    grid allows.
    """
    def starts(n: int) -> list[int]:
        if n <= tile:
            return [0]
        stride = tile - overlap
        count = int(np.ceil((n - overlap) / stride))
        return [int(round(i * (n - tile) / (count - 1))) for i in range(count)]

    rows, cols = shape
    return [(r, min(r + tile, rows), c, min(c + tile, cols))
            for r in starts(rows) for c in starts(cols)]


def tile_weight(shape: tuple[int, int], window: tuple[int, int, int, int], ramp: int
                ) -> np.ndarray:
    """Blending weight of a tile: 1 inside, falling linearly over ``ramp`` px to a small
    positive value at edges that are not the grid's own edges."""
    r0, r1, c0, c1 = window

    def profile(n: int, at_start: bool, at_end: bool) -> np.ndarray:
        i = np.arange(n, dtype=np.float64)
        w = np.ones(n)
        if not at_start:
            w = np.minimum(w, (i + 1) / (ramp + 1))
        if not at_end:
            w = np.minimum(w, (n - i) / (ramp + 1))
        return w

    wr = profile(r1 - r0, r0 == 0, r1 == shape[0])
    wc = profile(c1 - c0, c0 == 0, c1 == shape[1])
    return np.outer(wr, wc)


def refine_tiles(image: np.ndarray, dem: np.ndarray, *, spacing: tuple[float, float],
                 windows: list[tuple[int, int, int, int]], illuminations: list[Any],
                 parameters: Any = None, initial: np.ndarray | None = None,
                 ramp: int = 32, image_median: float | None = None
                 ) -> tuple[np.ndarray, list[Any]]:
    """Refine ``dem`` tile by tile (:func:`demtool.refine.refine_heights`) and blend.

    Parameters
    ----------
    image, dem : (H, W) float
        As for :func:`~demtool.refine.refine_heights` (the DEM finite).
    spacing : (dx, dy), metres
    windows : list of (row0, row1, col0, col1)
        Overlapping tiles covering the grid (:func:`overlapping_tiles`).
    illuminations : list of Illumination
        One per window, in the grid frame.
    parameters : SfsParameters, optional
    initial : (H, W) float, optional
        Starting heights.
    ramp : int
        Width of the blending ramps, px (about half the overlap).
    image_median : float, optional
        The whole image's median (the shadow threshold's scale); default: each tile's.

    Returns
    -------
    dem : (H, W) float32
        The blended refined heights.
    results : list of RefineResult
        One per tile.
    """
    from demtool.refine import refine_heights

    total = np.zeros(dem.shape)
    weights = np.zeros(dem.shape)
    results = []
    for window, illumination in zip(windows, illuminations, strict=True):
        r0, r1, c0, c1 = window
        start = None if initial is None else initial[r0:r1, c0:c1]
        result = refine_heights(image[r0:r1, c0:c1], dem[r0:r1, c0:c1], spacing=spacing,
                                illumination=illumination, parameters=parameters,
                                initial=start, image_median=image_median)
        w = tile_weight(dem.shape, window, ramp)
        total[r0:r1, c0:c1] += w * result.dem
        weights[r0:r1, c0:c1] += w
        results.append(result)
    return (total / weights).astype(np.float32), results
