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


def truth_map(field, placement, models, gsd_m: float, *, projection: str = "auto") -> TruthMap:
    """Truth heights above the sphere over the common footprint of ``models``.

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
    lon, lat = grid_lonlat(grid)
    heights = surface_height(placement, field, lon, lat)
    xyz = lonlat_height_to_xyz(lon, lat, np.nan_to_num(heights), radii=placement.radius)
    common = np.isfinite(heights)
    for model in models:
        common &= seen_by(model, xyz)
    if not common.any():
        raise ValueError("the views share no ground")
    rows = np.flatnonzero(common.any(axis=1))
    cols = np.flatnonzero(common.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    cropped = MapGrid(crs=grid.crs, transform=grid.transform @ Affine.translation(c0, r0),
                      width=int(c1 - c0), height=int(r1 - r0))
    values = np.where(common, heights, np.nan)[r0:r1, c0:c1].astype(np.float32)
    return TruthMap(cropped, values)
