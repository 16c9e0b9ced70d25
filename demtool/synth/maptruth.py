"""Truth DEM of a scene on a body, on the body's map (``truth_dem_map.tif``).

The grid: the body's IAU projection (:func:`demtool.maps.choose_projection`, ``auto``:
equirectangular centred on the footprint, polar stereographic poleward of ±70°) at
the images' ground sampling distance, snapped to whole pixels
(:func:`demtool.maps.grid_from_lonlat`) and cropped to the cells both views of the
stereo pair see (each cell's ground point projects inside both images through their
sensor models); NaN outside that common footprint.  The heights are the true
surface's radial heights above the reference sphere
(:func:`demtool.synth.body.surface_height`), exact for the plane-based local terrain.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from affine import Affine

from demtool.maps import MapGrid, grid_from_lonlat, grid_lonlat, lonlat_height_to_xyz
from demtool.maps import xyz_to_lonlat_height as to_lonlat
from demtool.synth import render
from demtool.synth.body import surface_height


class TruthMap(NamedTuple):
    """Truth heights on the body's map.

    grid : MapGrid
    heights : (rows, columns) float32, metres above the reference sphere, NaN outside
        the pair's common footprint.
    """

    grid: MapGrid
    heights: np.ndarray


def footprint_lonlat(model, field, placement, step: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Longitude and latitude (degrees) where the rays along the image border (every
    ``step`` pixels and the corners) hit the terrain; NaN for rays that miss."""
    lines, samples = model.lines, model.samples
    edge_l = np.union1d(np.arange(0.0, lines, step), [lines - 1.0])
    edge_s = np.union1d(np.arange(0.0, samples, step), [samples - 1.0])
    rows = np.concatenate([edge_l, edge_l, np.zeros_like(edge_s), np.full_like(edge_s,
                                                                                lines - 1.0)])
    cols = np.concatenate([np.zeros_like(edge_l), np.full_like(edge_l, samples - 1.0), edge_s,
                           edge_s])
    hits = render.pixel_hits(field, model, np.column_stack([cols, rows]), placement=placement)
    lon, lat, _ = to_lonlat(placement.to_body(hits), radii=placement.radius)
    return lon, lat


def seen_by(model, xyz: np.ndarray) -> np.ndarray:
    """True where body-fixed points (..., 3) project inside ``model``'s image."""
    line, sample = model.ground_to_image(xyz)
    return ((line >= 0) & (line <= model.lines) & (sample >= 0) & (sample <= model.samples))


#: cells of one block of grid rows (about 100 bytes a cell of temporaries)
BLOCK_CELLS = 1 << 21
#: grids of more cells decide most cells' "seen" from a lattice (:class:`_SeenLattice`)
LATTICE_MIN_CELLS = 1 << 22
LATTICE_STEP = 16  # cells between lattice nodes
LATTICE_MARGIN_PX = 2.0  # beyond the relief's parallax, for the interpolation


def _block(grid: MapGrid, first: int, stop: int) -> MapGrid:
    """Rows ``first … stop − 1`` of ``grid`` as a grid of their own."""
    if first == 0 and stop == grid.height:
        return grid
    return MapGrid(crs=grid.crs, transform=grid.transform @ Affine.translation(0, first),
                   width=grid.width, height=stop - first)


class _SeenLattice:
    """Image positions of every ``LATTICE_STEP``-th cell of a grid in each model, from
    which :meth:`seen` decides the cells far from an image edge without projecting
    them; the cells within ``margin`` pixels of an edge are projected exactly.

    The margin is the largest image shift of 1 m of radial height at any node, times
    the spread of heights the surface can take (lattice heights and the DEM's range),
    plus ``LATTICE_MARGIN_PX``: the bilinear interpolation of positions between nodes
    errs only by the parallax of the height difference to the interpolated one.
    """

    def __init__(self, grid: MapGrid, field, placement, models):
        rows, cols = grid.shape
        self.rows = np.union1d(np.arange(0, rows, LATTICE_STEP), [rows - 1])
        self.cols = np.union1d(np.arange(0, cols, LATTICE_STEP), [cols - 1])
        t = grid.transform
        c, r = self.cols[None, :] + 0.5, self.rows[:, None] + 0.5
        x, y = t.a * c + t.b * r + t.c, t.d * c + t.e * r + t.f
        from demtool.maps import map_to_lonlat

        lon, lat = map_to_lonlat(grid.crs, *np.broadcast_arrays(x, y))
        heights = surface_height(placement, field, lon, lat)
        spread = float(np.nanmax(heights) - np.nanmin(heights)) + field.z_max - field.z_min
        xyz = lonlat_height_to_xyz(lon, lat, np.nan_to_num(heights), radii=placement.radius)
        up = xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)
        self.positions, self.margins = [], []
        for model in models:
            line, sample = model.ground_to_image(xyz)
            line_up, sample_up = model.ground_to_image(xyz + up)
            shift = np.nanmax(np.hypot(line_up - line, sample_up - sample))
            self.positions.append((line, sample))
            self.margins.append(float(shift) * spread + LATTICE_MARGIN_PX)

    def _interpolate(self, values: np.ndarray, first: int, stop: int, cols: int) -> np.ndarray:
        fr = np.interp(np.arange(first, stop), self.rows, np.arange(len(self.rows)))
        fc = np.interp(np.arange(cols), self.cols, np.arange(len(self.cols)))
        r0 = np.minimum(fr.astype(np.int64), len(self.rows) - 2) if len(self.rows) > 1 \
            else np.zeros(len(fr), dtype=np.int64)
        c0 = np.minimum(fc.astype(np.int64), len(self.cols) - 2) if len(self.cols) > 1 \
            else np.zeros(len(fc), dtype=np.int64)
        a, b = (fr - r0)[:, None], fc - c0
        r1 = np.minimum(r0 + 1, len(self.rows) - 1)
        c1 = np.minimum(c0 + 1, len(self.cols) - 1)
        band = values[r0] * (1.0 - a) + values[r1] * a
        return band[:, c0] * (1.0 - b) + band[:, c1] * b

    def seen(self, index: int, model, xyz: np.ndarray, first: int, stop: int,
             candidates: np.ndarray) -> np.ndarray:
        """``seen_by(model, xyz)`` over ``candidates`` (False elsewhere) for grid rows
        ``first … stop − 1``."""
        cols = xyz.shape[1]
        line = self._interpolate(self.positions[index][0], first, stop, cols)
        sample = self._interpolate(self.positions[index][1], first, stop, cols)
        m = self.margins[index]
        inside = (line >= m) & (line <= model.lines - m) & (sample >= m) & \
            (sample <= model.samples - m)
        outside = (line < -m) | (line > model.lines + m) | (sample < -m) | \
            (sample > model.samples + m)
        out = candidates & inside
        exact = candidates & ~inside & ~outside
        if exact.any():
            out[exact] = seen_by(model, xyz[exact])
        return out


def truth_map(field, placement, models, gsd_m: float, *, projection: str = "auto") -> TruthMap:
    """Truth heights above the sphere over the common footprint of ``models``.

    The grid is filled in blocks of rows (``BLOCK_CELLS``); on grids of more than
    ``LATTICE_MIN_CELLS`` cells, only the cells near an image edge are projected into
    the models (:class:`_SeenLattice`), the same decision at a fraction of the cost.

    Parameters
    ----------
    field : demtool.synth.render.HeightField
        The scene's terrain, local frame.
    placement : demtool.synth.body.Placement
    models : sequence of SensorModel
        Body-fixed models (the stereo pair).
    gsd_m : float
        Grid spacing, metres (the images' GSD).
    projection : {"auto", "equirectangular", "polar-stereographic"}

    Returns
    -------
    TruthMap

    Raises
    ------
    ValueError
        When the views share no ground.
    """
    lons, lats = zip(*(footprint_lonlat(m, field, placement) for m in models), strict=True)
    grid = grid_from_lonlat(placement.body, np.concatenate(lons), np.concatenate(lats), gsd_m,
                            projection=projection, polygon=False)
    rows, cols = grid.shape
    lattice = _SeenLattice(grid, field, placement, models) \
        if rows * cols > LATTICE_MIN_CELLS else None
    values = np.full(grid.shape, np.nan, dtype=np.float32)
    common = np.zeros(grid.shape, dtype=bool)
    step = max(1, BLOCK_CELLS // max(cols, 1))
    for first in range(0, rows, step):
        stop = min(first + step, rows)
        lon, lat = grid_lonlat(_block(grid, first, stop))
        heights = surface_height(placement, field, lon, lat)
        xyz = lonlat_height_to_xyz(lon, lat, np.nan_to_num(heights), radii=placement.radius)
        seen = np.isfinite(heights)
        for index, model in enumerate(models):
            seen = seen & seen_by(model, xyz) if lattice is None else \
                lattice.seen(index, model, xyz, first, stop, seen)
        common[first:stop] = seen
        values[first:stop] = np.where(seen, heights, np.nan)
    if not common.any():
        raise ValueError("the views share no ground")
    rows_seen = np.flatnonzero(common.any(axis=1))
    cols_seen = np.flatnonzero(common.any(axis=0))
    r0, r1, c0, c1 = rows_seen[0], rows_seen[-1] + 1, cols_seen[0], cols_seen[-1] + 1
    cropped = MapGrid(crs=grid.crs, transform=grid.transform @ Affine.translation(c0, r0),
                      width=int(c1 - c0), height=int(r1 - r0))
    return TruthMap(cropped, np.ascontiguousarray(values[r0:r1, c0:c1]))
