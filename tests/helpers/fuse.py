"""DEMs of one lunar area for the fuse tests: a smooth truth, pair-like DEMs of it with
known noise, extents and shifts, written on an equirectangular map of the Moon."""

from __future__ import annotations

import numpy as np
from affine import Affine

GSD = 2.0  # metres per cell
ORIGIN = (-200.0, 200.0)  # x west, y north of the common lattice, metres


def moon_crs(body_id: int = 301):
    from rasterio.crs import CRS

    from demtool import maps

    body = maps.body_by_naif_id(body_id)
    return CRS.from_wkt(maps.make_projection(body, "equirectangular", 0.0, 0.0).to_wkt()), body


def truth_heights(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Smooth relief (metres) at cell centres of the common lattice (rows down, cols right)."""
    x, y = (cols + 0.5) * GSD, (rows + 0.5) * GSD
    return (6.0 * np.sin(2 * np.pi * x / 90.0) + 4.0 * np.cos(2 * np.pi * (y + 0.4 * x) / 70.0)
            + 0.002 * x * y / 10)


def write_dem(path, window, *, noise=0.0, seed=0, shift=(0.0, 0.0, 0.0), body_id=301,
              outliers=0.0):
    """Write the truth over ``window`` = (row0, row1, col0, col1) of the lattice.

    ``shift`` (dx, dy cells; dz metres) displaces the DEM (so fuse must add −shift);
    ``outliers``: fraction of cells replaced by +50 m blunders.  Returns the heights.
    """
    from demtool import io as dio

    r0, r1, c0, c1 = window
    rows, cols = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    dx, dy, dz = shift
    heights = truth_heights(rows - dy, cols - dx) + dz
    rng = np.random.default_rng(seed)
    heights = heights + noise * rng.standard_normal(heights.shape)
    if outliers:
        heights[rng.random(heights.shape) < outliers] += 50.0
    crs, body = moon_crs(body_id)
    transform = Affine(GSD, 0, ORIGIN[0] + c0 * GSD, 0, -GSD, ORIGIN[1] - r0 * GSD)
    dio.write_raster(path, heights, transform=transform, crs=crs, tags=body.tags())
    return heights


def write_error(path, window, value, body_id=301):
    """A constant error raster (metres) on ``window``'s grid."""
    from demtool import io as dio

    r0, r1, c0, c1 = window
    crs, body = moon_crs(body_id)
    transform = Affine(GSD, 0, ORIGIN[0] + c0 * GSD, 0, -GSD, ORIGIN[1] - r0 * GSD)
    dio.write_raster(path, np.full((r1 - r0, c1 - c0), value), transform=transform, crs=crs,
                     tags=body.tags())
