"""The grids of ``demtool fuse``: each DEM's, their union (the fused grid), the windows
of one on another, and the grid co-registration samples on."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np


def grid_of(info):
    from demtool.fuse.tiled import GridSpec

    return GridSpec.of((info.height, info.width), info.transform, info.crs)


def bounds_in(spec, crs) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) of a grid in ``crs``'s coordinates."""
    grid = spec.grid()
    bounds = grid.bounds()
    if grid.crs is not None and crs is not None and grid.crs != crs:
        from rasterio.warp import transform_bounds

        return tuple(transform_bounds(grid.crs, crs, *bounds, densify_pts=21))
    return bounds


def union_grid(specs: Sequence[Any], first: Any):
    """The grid covering every spec's extent, on ``first``'s CRS, spacing and lattice."""
    from affine import Affine

    from demtool.fuse.tiled import GridSpec

    t = first.affine()
    if t.b != 0 or t.d != 0:
        return first
    crs = first.crs()
    boxes = np.array([bounds_in(s, crs) for s in specs])
    xmin, ymin = boxes[:, 0].min(), boxes[:, 1].min()
    xmax, ymax = boxes[:, 2].max(), boxes[:, 3].max()
    # snap to the first grid's lattice
    c0 = math.floor((xmin - t.c) / t.a + 1e-6) if t.a > 0 else math.floor((xmax - t.c) / t.a)
    c1 = math.ceil((xmax - t.c) / t.a - 1e-6) if t.a > 0 else math.ceil((xmin - t.c) / t.a)
    if t.e < 0:
        r0 = math.floor((ymax - t.f) / t.e + 1e-6)
        r1 = math.ceil((ymin - t.f) / t.e - 1e-6)
    else:
        r0 = math.floor((ymin - t.f) / t.e + 1e-6)
        r1 = math.ceil((ymax - t.f) / t.e - 1e-6)
    transform = t @ Affine.translation(c0, r0)
    return GridSpec((r1 - r0, c1 - c0), (transform.a, transform.b, transform.c, transform.d,
                                         transform.e, transform.f), first.crs_wkt)


def t_srs_grid(text: str, specs: Sequence[Any], first_path):
    """The grid of ``--t-srs``: the union of the DEMs' extents on that CRS, at the first
    DEM's spacing (metres), snapped to multiples of it.  ParameterError (one line) for a
    CRS PROJ does not know, not projected, of another body than the DEMs', or whose
    surface (sphere or ellipsoid) differs from the first DEM's: the heights would keep
    their own reference."""
    from rasterio.crs import CRS as RioCRS

    from demtool.errors import ParameterError
    from demtool.fuse.tiled import GridSpec
    from demtool.maps import body_from_crs, crs_surface, degree_pixel_size, snap_grid
    from demtool.maps.crs_option import parse_t_srs

    first = specs[0]
    if first.crs_wkt is None:
        raise ParameterError(f"--t-srs {text}: {first_path} has no CRS to reproject from")
    try:
        crs = parse_t_srs(text, body_from_crs(first.crs_wkt))
    except ValueError as exc:
        raise ParameterError(str(exc)) from None
    if crs_surface(crs) != crs_surface(first.crs_wkt):
        raise ParameterError(f"--t-srs {text}: its surface ({crs_surface(crs)}) is not that "
                             f"of {first_path} ({crs_surface(first.crs_wkt)}); the heights "
                             "would keep their own reference")
    boxes = np.array([bounds_in(s, RioCRS.from_wkt(crs.to_wkt())) for s in specs])
    t = first.affine()
    if first.crs().is_geographic:
        centre = t.f + 0.5 * t.e * first.shape[0]
        sx, sy = degree_pixel_size(t, centre, body_from_crs(first.crs_wkt).a)
        gsd = math.sqrt(sx * sy)
    else:
        gsd = math.sqrt(abs(t.a * t.e - t.b * t.d))
    grid = snap_grid(crs, boxes[:, 0].min(), boxes[:, 1].min(), boxes[:, 2].max(),
                     boxes[:, 3].max(), gsd)
    return GridSpec(grid.shape, tuple(grid.transform)[:6], crs.to_wkt())


def cells_of(spec, target) -> tuple[int, int, int, int] | None:
    """The window (row0, row1, col0, col1) of ``target`` that ``spec``'s extent covers."""
    xmin, ymin, xmax, ymax = bounds_in(spec, target.crs())
    inverse = ~target.affine()
    corners = np.array([inverse @ (x, y) for x in (xmin, xmax) for y in (ymin, ymax)])
    c0, r0 = np.floor(corners.min(axis=0) + 1e-6).astype(int)
    c1, r1 = np.ceil(corners.max(axis=0) - 1e-6).astype(int)
    r0, c0 = max(0, int(r0)), max(0, int(c0))
    r1, c1 = min(target.shape[0], int(r1)), min(target.shape[1], int(c1))
    if r0 >= r1 or c0 >= c1:
        return None
    return r0, r1, c0, c1


def centred(window: tuple[int, int, int, int], size: int) -> tuple[int, int, int, int]:
    r0, r1, c0, c1 = window
    h, w = min(size, r1 - r0), min(size, c1 - c0)
    rs, cs = r0 + (r1 - r0 - h) // 2, c0 + (c1 - c0 - w) // 2
    return rs, rs + h, cs, cs + w


def intersect(a, b):
    r0, r1 = max(a[0], b[0]), min(a[1], b[1])
    c0, c1 = max(a[2], b[2]), min(a[3], b[3])
    return (r0, r1, c0, c1) if r0 < r1 and c0 < c1 else None


def coreg_grid(target, window: tuple[int, int, int, int], spacings: Sequence[float],
                coreg_size: int):
    """The grid co-registration samples on: ``target``'s cells in ``window``, refined by
    an integer factor when the DEMs are finer than the fused grid (its first DEM's) and
    the window is small, so that a coarse first DEM leaves the others' relief to fit
    (issue 46: a coarse DEM first gave "barely overlap" on DEMs that overlap fully).

    Returns
    -------
    grid : GridSpec
    window : (row0, row1, col0, col1)
        Cells of ``grid``.
    factor : int
        Fused-grid cells are ``factor`` times the returned grid's.
    """
    from affine import Affine

    from demtool.fuse.tiled import GridSpec

    r0, r1, c0, c1 = window
    t = target.affine()
    cell = float(np.sqrt(abs(t.a * t.e - t.b * t.d)))
    finest = min([s for s in spacings if s > 0] or [cell])
    side = max(r1 - r0, c1 - c0)
    factor = max(1, min(int(cell / finest + 1e-6), coreg_size // max(side, 1)))
    if factor == 1:
        return target, window, 1
    fine = t @ Affine.scale(1.0 / factor)
    shape = (target.shape[0] * factor, target.shape[1] * factor)
    grid = GridSpec(shape, (fine.a, fine.b, fine.c, fine.d, fine.e, fine.f), target.crs_wkt)
    return grid, (r0 * factor, r1 * factor, c0 * factor, c1 * factor), factor


def spacing_of(spec) -> float:
    t = spec.affine()
    return float(np.sqrt(abs(t.a * t.e - t.b * t.d)))
