"""The reference DEM of ``bundle --reference-dem``: checked against the sensor models'
body and read (the window under the images' footprints) into a
:class:`demtool.bundle.surface.ReferenceSurface`."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np


def read_reference_surface(path: str | os.PathLike, models: Sequence[Any],
                           sensor_paths: Sequence[str | os.PathLike], *, sigma: float,
                           slope_sigma: bool = True):
    """The reference DEM under the images, heights above the models' body's sphere.

    Parameters
    ----------
    path : path-like
        A DEM on the body's map (projected or geographic CRS on the body's sphere),
        heights in metres.
    models : sequence of SensorModel
        The prior models (their radii name the body; their footprints on the sphere
        choose the window read).
    sensor_paths : sequence of path-like
        The models' files, for messages.
    sigma : float
        Standard deviation of the DEM's heights, metres.
    slope_sigma : bool
        Add each tie point's interpolation error, bilinear interpolation's bound
        post² / 8 × local curvature and the measured share of post spacing × local
        slope it leaves (:meth:`demtool.bundle.surface.ReferenceSurface.point_sigmas`),
        to ``sigma``.

    Raises
    ------
    InputError
        No CRS (units and body unknown, e.g. a grid in degrees without its body),
        another body than the models', an ellipsoid instead of the sphere, or a DEM
        that does not cover the images.
    """
    from affine import Affine

    from demtool import io as dio
    from demtool.bundle.surface import ReferenceSurface
    from demtool.errors import InputError
    from demtool.mapproject.core import ground_footprint, sensor_body
    from demtool.mapproject.surface import read_dem_surface
    from demtool.maps import lonlat_to_map, to_pyproj_crs, wrap_longitude, xyz_to_lonlat_height

    dio.require_file(path, "reference DEM")
    index = next((i for i, m in enumerate(models) if m.radii is not None), None)
    if index is None:
        raise InputError(f"{path}: --reference-dem needs the body's radii, and no sensor "
                         "model carries them (.tsai files do not): give ISDs or cubes")
    body = sensor_body(models[index])
    info = dio.raster_info(path, what="reference DEM")
    if info.crs is None:
        raise InputError(f"{path}: reference DEM has no CRS, so its body and units (metres "
                         "or degrees) are unknown; give a DEM on the body's map")
    dem = read_dem_surface(path, sensor_paths[index], body)  # same body, on the sphere
    crs = to_pyproj_crs(info.crs)
    lons, lats = [], []
    for model in models:
        xyz = ground_footprint(model, body.radius, 0.0)
        xyz = xyz[np.isfinite(xyz).all(axis=1)]
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=body.radius)
        lons.append(lon)
        lats.append(lat)
    lon, lat = np.concatenate(lons), np.concatenate(lats)
    t = info.transform
    if crs.is_geographic:
        x, y = wrap_longitude(lon, t.c + 0.5 * t.a * info.width), lat
    else:
        x, y = lonlat_to_map(crs, lon, lat)
    inverse = ~t
    col = inverse.a * x + inverse.b * y + inverse.c
    row = inverse.d * x + inverse.e * y + inverse.f
    good = np.isfinite(col) & np.isfinite(row)
    if not good.any():
        raise InputError(f"{path}: reference DEM does not cover the images' footprints")
    c0 = max(math.floor(col[good].min()) - 2, 0)
    c1 = min(math.ceil(col[good].max()) + 2, info.width)
    r0 = max(math.floor(row[good].min()) - 2, 0)
    r1 = min(math.ceil(row[good].max()) + 2, info.height)
    if c1 <= c0 or r1 <= r0:
        raise InputError(f"{path}: reference DEM does not cover the images' footprints")
    from demtool.bundle.surface import measuring_window

    # the window the interpolation factor is measured on: the footprints' or, where they
    # cover fewer posts, the FACTOR_POSTS around them
    wide = measuring_window((r0, r1, c0, c1), (info.height, info.width))
    values = dio.read_window(path, wide, what="reference DEM").astype(np.float64)
    inner = np.s_[r0 - wide[0]:r1 - wide[0], c0 - wide[2]:c1 - wide[2]]
    if not np.isfinite(values[inner]).any():
        raise InputError(f"{path}: reference DEM has no data under the images' footprints")
    values = values + dem.offset_m  # heights above the body's sphere (radii: minus R)
    heights = values[inner]
    from demtool.mapproject.checks import check_surface_heights

    check_surface_heights(heights, path, body)
    surface = ReferenceSurface(heights=heights, transform=t @ Affine.translation(c0, r0),
                               crs=crs, radius=body.radius, sigma=float(sigma))
    if not slope_sigma:
        return surface
    centre = np.nanmean(np.concatenate([ground_footprint(m, body.radius, 0.0) for m in models]),
                     axis=0)
    import dataclasses

    from demtool.bundle.surface import curvature_error, interpolation_factor

    post_m, factor = surface.post_spacing_m(centre), interpolation_factor(values)
    curvature = curvature_error(heights)
    with np.errstate(invalid="ignore"):
        rows, cols = np.gradient(heights, post_m)
        slope_m = factor * post_m * np.hypot(rows, cols)
        typical = float(np.nanmedian(np.hypot(slope_m, curvature)))
    from demtool.logs import get_logger

    log = get_logger("demtool.bundle")
    if not typical > sigma:
        # a DEM fine enough that its interpolation error at a typical post is within its
        # stated sigma: sigma covers it (weighting curved or steep tie points down would
        # only loosen the datum's tie where the DEM resolves the ground)
        log.info("reference DEM %s: interpolation error %.3g m at the median post (%.4g m "
                 "posts) is within --reference-dem-sigma %.3g m: sigma alone", path,
                 typical, post_m, sigma)
        return surface
    log.info("reference DEM %s: %.4g m posts, interpolation error (bilinear bound post^2/8 "
             "x curvature, median %.3g m, and %.3g x post x slope, median %.3g m; together "
             "%.3g m at the median post) added to --reference-dem-sigma %.3g m per tie "
             "point", path, post_m, float(np.nanmedian(curvature)), factor,
             float(np.nanmedian(slope_m)), typical, sigma)
    return dataclasses.replace(surface, post_m=post_m, slope_factor=factor,
                               curvature=curvature)
