"""Comparing DEMs on planetary CRSs: one body only, and degree grids turned into metres.

* :func:`check_bodies` — the body of each raster's CRS (:func:`demtool.maps.body_from_crs`:
  from PROJ's ``IAU_2015`` codes, the datum / ellipsoid names, or the radii; Earth
  ellipsoids are Earth); DEMs of different bodies are refused in one line naming both
  files, and CRSs of one body on different reference surfaces (a Mars sphere and the
  Mars ellipsoid) give a warning, since their heights may be relative to different
  surfaces.
* :func:`metric_grid` — a geographic (degree) grid is never measured in degrees: the
  comparison moves to a metric grid over the same footprint on the same datum
  (:func:`demtool.maps.metric_grid_for`: equirectangular centred on the footprint, polar
  stereographic poleward of ±70°), whose pixel is the degree pixel's ground size at the
  footprint's centre, computed with the body's radius.  Spacing, slopes, shifts and the
  effective resolution are then in metres.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from demtool.compare.grids import Grid
from demtool.errors import InputError
from demtool.logs import get_logger
from demtool.maps.bodies import body_label

__all__ = ["check_bodies", "metric_grid", "radius_offset"]

log = get_logger(__name__)

# Reference surfaces of one body closer than this (metres, in a and in c) are the same.
SURFACE_TOLERANCE_M = 1.0


def check_bodies(rasters: Sequence[tuple[str | os.PathLike, Any]]) -> list[str]:
    """Refuse rasters of different bodies; warn about different reference surfaces.

    Parameters
    ----------
    rasters : sequence of (path, crs)
        The reference first, then the DEMs; rasters without CRS (image frames, local
        maps) are skipped.

    Returns
    -------
    list of str
        Warnings (one per raster whose CRS is on another reference surface of the same
        body than the first georeferenced raster's).

    Raises
    ------
    InputError
        One line naming both files and both bodies when two rasters are on different
        bodies (e.g. a Mars DEM and a Moon DEM, or an Earth CRS and a Moon CRS).
    """
    from demtool.maps import body_from_crs, same_body

    first: tuple[Any, Any] | None = None
    warnings: list[str] = []
    for path, crs in rasters:
        if crs is None:
            continue
        body = body_from_crs(crs)
        if first is None:
            first = (path, body)
            continue
        first_path, first_body = first
        if not same_body(body, first_body):
            raise InputError(f"{path}: is on {body_label(body)} but {first_path} is on "
                             f"{body_label(first_body)}; compare DEMs of one body")
        if abs(body.a - first_body.a) > SURFACE_TOLERANCE_M or \
                abs(body.c - first_body.c) > SURFACE_TOLERANCE_M:
            message = (f"{path} is on {body_label(body)} but {first_path} on "
                       f"{body_label(first_body)}: their heights may be relative to "
                       "different reference surfaces")
            log.warning("%s", message)
            warnings.append(message)
    return warnings


def metric_grid(grid: Grid) -> tuple[Grid, dict[str, Any] | None]:
    """The grid a comparison is measured on: ``grid`` itself, or a metric one for degrees.

    Parameters
    ----------
    grid : Grid
        The chosen comparison grid (the reference's or the DEM's).

    Returns
    -------
    (Grid, dict or None)
        ``grid`` and None when its CRS is not geographic; otherwise the metric grid (a
        projected CRS on the same datum, pixel size in metres) and a note for the report:
        ``{"crs": the geographic CRS, "spacing_deg": [x, y], "shape": [rows, cols],
        "projection": the metric CRS's name, "spacing_m": [x, y]}``.
    """
    from demtool.maps import metric_grid_for, to_pyproj_crs

    if grid.crs is None or not to_pyproj_crs(grid.crs).is_geographic:
        return grid, None
    from rasterio.crs import CRS

    metric = metric_grid_for(grid.crs, grid.transform, grid.shape)
    out = Grid(shape=metric.shape, transform=metric.transform,
               crs=CRS.from_wkt(metric.crs.to_wkt()))
    note = {"crs": to_pyproj_crs(grid.crs).to_string(), "spacing_deg": list(grid.spacing),
            "shape": list(grid.shape), "projection": metric.crs.name,
            "spacing_m": list(metric.gsd)}
    log.info("the comparison grid is in degrees (%.6g x %.6g deg): measuring on %s at "
             "%.4g m", grid.spacing[0], grid.spacing[1], metric.crs.name, metric.gsd[0])
    return out, note


def radius_offset(path: str | os.PathLike, crs, values, what: str) -> float:
    """The body's radius when a DEM on a planetary map holds radii (ISIS shape models:
    LOLA ``ldem_*``, MOLA), else 0: the metres to subtract for heights (one log line)."""
    import numpy as np

    from demtool.maps import body_from_crs, holds_radii, to_pyproj_crs

    if crs is None:
        return 0.0
    try:
        radius = float(body_from_crs(to_pyproj_crs(crs)).radius)
    except (ValueError, TypeError, AttributeError):
        return 0.0  # not a body's map: heights as they are
    if not holds_radii(values, radius):
        return 0.0
    from demtool.logs import get_logger

    get_logger("demtool.compare").info("%s %s holds radii (median %.1f m): heights are the "
                                       "radii minus %.1f m", what, path,
                                       float(np.nanmedian(values)), radius)
    return radius
