"""What the ``refine`` runner and its tiled job read and prepare: the image on the DEM's
grid, the sun (given, from the image's tags or from its sensor model) and the map route.

:func:`resolve_illumination` and :func:`image_on_dem_grid` serve every route.  The map
route (a DEM on the body's map refined with a map-projected image whose sun and view
directions come from its sensor model) is used by :func:`demtool.refine.run.run_refine`
when the DEM has a CRS:

* a DEM in geographic degrees is put on a metric grid of the same footprint
  (:func:`demtool.maps.metric_grid_for`, the body's sphere radius) or, for a body
  PROJ does not know, refused;
* the image is an orthoimage of ``demtool mapproject`` (its tags name the sensor model),
  or a raw image with ``--sensor`` that is map-projected onto the DEM here; an image on
  a map with neither (a mosaic) has no single sun and is refused unless the sun is given;
* the sun and view directions are taken from the sensor model in each point's local
  east-north-up frame (:mod:`demtool.refine.geometry`): one pair for the whole DEM when
  they vary by less than ``max_illumination_change`` degrees over it, else one pair per
  overlapping tile (:mod:`demtool.refine.tiles`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from demtool.errors import InputError
from demtool.stagerun import check_same_frame

if TYPE_CHECKING:
    from demtool.io import Raster
    from demtool.refine import Illumination

SENSOR_TAG = "mapproject_sensor"
LATTICE = 9  # points per side where the directions are sampled


class MapGeometry(NamedTuple):
    """What the map route resolved: the DEM (metric grid), the image on it, and the
    illumination (one pair or per tile)."""

    dem: Any  # demtool.io.Raster on a metric grid
    values: np.ndarray
    windows: list[tuple[int, int, int, int]] | None
    illuminations: list[Any]
    report: dict[str, Any]


def metric_dem(dem, log):
    """The DEM itself when projected; on a metric grid when in degrees (or refused)."""
    from demtool import io as dio
    from demtool.compare.grids import Grid, resample_to_grid
    from demtool.maps import body_from_crs, metric_grid_for, to_pyproj_crs

    crs = to_pyproj_crs(dem.crs)
    if not crs.is_geographic:
        return dem, None
    body = body_from_crs(crs)
    if body.naif_id is None:
        raise InputError(f"{dem.path}: DEM is in degrees on an unknown body ({body.name}); "
                         "without the body's radius its slopes cannot be measured in metres: "
                         "reproject it onto a projected CRS of the body")
    grid = metric_grid_for(crs, dem.transform, dem.data.shape)
    values = resample_to_grid(dem.data, Grid(dem.data.shape, dem.transform, dem.crs),
                              Grid(grid.shape, grid.transform, grid.crs)).astype(np.float32)
    note = (f"DEM in degrees put on {grid.crs.name} at {grid.gsd[0]:.4g} m "
            f"({grid.width} x {grid.height}) with the radius of {body.name}")
    log.info("%s: %s", dem.path, note)
    return dio.Raster(data=values, transform=grid.transform, crs=grid.crs,
                      tags=dict(dem.tags), path=dem.path), note


def _sensor_path(image, sensor_path) -> Path | None:
    if sensor_path is not None:
        return Path(sensor_path)
    tagged = image.tags.get(SENSOR_TAG)
    return Path(tagged) if tagged else None


def _is_map_image(image_path) -> bool:
    """Whether an image lies on a map (a CRS): an orthoimage, never a raw image."""
    from demtool import io as dio

    return dio.raster_info(image_path, what="image").crs is not None


def image_on_map(image_path, sensor_path, dem, params, log):
    """The image's values on the DEM grid and its sensor model.

    A raw image with ``sensor_path`` is map-projected onto the DEM; an orthoimage is
    resampled onto the DEM grid when its grid differs, its sensor model the one its tags
    name (or ``sensor_path``, which must then be that model:
    :func:`demtool.mapproject.hashes.check_own_sensor`).
    """
    from demtool import io as dio
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.hashes import check_hashes, check_own_sensor
    from demtool.mapproject.surface import orthoimage_on_grid, require_same_body
    from demtool.sensors import read_sensor

    if sensor_path is not None and not _is_map_image(image_path):
        sensor = read_sensor(sensor_path)
        require_same_body(dem.path, dem.crs, sensor_body(sensor), sensor_path, "a DEM")
        values = orthoimage_on_grid(image_path, sensor, dem)
        log.info("%s map-projected through %s onto the DEM grid", image_path, sensor_path)
        return values, sensor, Path(sensor_path)
    image = dio.read_image(image_path, what="image")
    if sensor_path is not None:
        path = Path(sensor_path)
        if check_own_sensor(image_path, image.tags, path):
            check_hashes(image_path, image.tags, log=log)
        else:
            log.info("%s: a map image recording no sensor model: its sun and view are taken "
                     "from --sensor %s", image_path, path)
    else:
        path = _sensor_path(image, None)
        if path is None:
            return None, None, None
        if not path.is_file():
            raise InputError(f"{image_path}: its sensor model {path} (tag {SENSOR_TAG}) is "
                             "not found; give --sensor")
        check_hashes(image_path, image.tags, log=log)
    sensor = read_sensor(path)
    require_same_body(dem.path, dem.crs, sensor_body(sensor), path, "a DEM")
    values, note = image_on_dem_grid(image, dem)
    if note:
        log.info("%s", note)
    return values, sensor, path


def map_illumination(sensor, dem, params, log):
    """One (sun, view) pair, or overlapping tiles with one pair each."""
    from demtool.errors import ParameterError
    from demtool.refine import make_illumination
    from demtool.refine.geometry import angular_spread, illumination_grid
    from demtool.refine.tiles import overlapping_tiles

    h, w = dem.data.shape
    t = dem.transform
    filled = np.where(np.isfinite(dem.data), dem.data, np.nanmedian(dem.data))

    def directions(rows, cols):
        rows = np.clip(np.asarray(rows), 0, h - 1)
        cols = np.clip(np.asarray(cols), 0, w - 1)
        x = t.a * (cols + 0.5) + t.c
        y = t.e * (rows + 0.5) + t.f
        return illumination_grid(sensor, dem.crs, x, y, filled[rows, cols])

    rr, cc = np.meshgrid(np.linspace(0, h - 1, LATTICE).round().astype(int),
                         np.linspace(0, w - 1, LATTICE).round().astype(int), indexing="ij")
    lattice = directions(rr, cc)
    if not lattice.seen.any():
        raise InputError(f"{sensor.name}: the sensor model sees none of the DEM")
    spread = max(angular_spread(lattice.sun), angular_spread(lattice.view))
    report = {"illumination_spread_deg": round(spread, 4),
              "max_illumination_change_deg": params.max_illumination_change}

    def pair(sun, view, where):
        try:
            return make_illumination(sun, view)
        except ParameterError as exc:
            raise ParameterError(f"{sensor.name} at {where}: {exc}") from None

    if spread <= params.max_illumination_change:
        sun = np.nanmean(lattice.sun.reshape(-1, 3), axis=0)
        view = np.nanmean(lattice.view.reshape(-1, 3), axis=0)
        log.info("sun and view from %s vary by %.2f deg over the DEM: one pair", sensor.name,
                 spread)
        return None, [pair(sun, view, "the DEM")], report
    windows = overlapping_tiles((h, w), params.illumination_tile,
                                max(params.illumination_tile // 4, 16))
    centres = directions([(r0 + r1) // 2 for r0, r1, _, _ in windows],
                         [(c0 + c1) // 2 for _, _, c0, c1 in windows])
    pairs = []
    for k, window in enumerate(windows):
        if not centres.seen[k]:
            raise InputError(f"{sensor.name}: the sensor model does not see the centre of "
                             f"DEM tile {window}")
        pairs.append(pair(centres.sun[k], centres.view[k], f"tile {window}"))
    report["tiles"] = len(windows)
    log.info("sun and view from %s vary by %.2f deg over the DEM: %d tiles of %d px",
             sensor.name, spread, len(windows), params.illumination_tile)
    return windows, pairs, report


def resolve_map_route(image_path: str | os.PathLike, dem, params, log, *,
                      sensor_path: str | os.PathLike | None) -> MapGeometry:
    """The map route's inputs for a DEM on a metric map grid (:func:`metric_dem`).

    Raises
    ------
    InputError
        A mosaic (a map image with no sensor model) without a given sun, a DEM in
        degrees of an unknown body, a sensor that does not see the DEM.
    """
    values, sensor, path = image_on_map(image_path, sensor_path, dem, params, log)
    if sensor is None:
        raise InputError(f"{image_path}: a map image without a sensor model (no "
                         f"{SENSOR_TAG} tag; a mosaic?) has no single sun and view "
                         "geometry: map-project the raw image (demtool mapproject), give "
                         "--sensor, or give the sun")
    if values is not None and not np.isfinite(values).any():  # before any sun or view
        raise InputError(f"{dem.path}: the DEM lies outside the footprint of {image_path} "
                         f"(through {path}): no DEM cell is in the image")
    windows, pairs, report = map_illumination(sensor, dem, params, log)
    report["sensor"] = str(path)
    return MapGeometry(dem, np.asarray(values, dtype=np.float32), windows, pairs, report)


def resolve_illumination(image: Raster, *, sun_azimuth: float | None = None,
                         sun_elevation: float | None = None,
                         sun_vector: tuple[float, float, float] | None = None,
                         view_vector: tuple[float, float, float] | None = None
                         ) -> tuple[Illumination, dict[str, str]]:
    """Sun and view directions (grid frame) from the options, else the image's tags.

    Returns
    -------
    illumination : Illumination
    sources : dict
        Where each vector came from (``"option"``, ``"tag sun_vector_grid"``, …).

    Raises
    ------
    ParameterError
        No sun direction anywhere, or a sun at or below the horizon.
    """
    from demtool.errors import ParameterError
    from demtool.refine import make_illumination, sun_from_angles

    if sun_vector is not None:
        sun, sun_source = sun_vector, "--sun-vector"
    elif sun_azimuth is not None and sun_elevation is not None:
        if sun_elevation <= 0:
            raise ParameterError(f"--sun-elevation {sun_elevation:g}: the sun is below the "
                                 "horizon; shape from shading needs a lit surface")
        sun, sun_source = sun_from_angles(sun_azimuth, sun_elevation), \
            "--sun-azimuth/--sun-elevation"
    elif image.tag_json("sun_vector_grid") is not None:
        sun, sun_source = image.tag_json("sun_vector_grid"), f"tag sun_vector_grid of {image.path}"
    else:
        raise ParameterError(f"{image.path}: no sun direction: the image has no "
                             "'sun_vector_grid' tag; give --sun-azimuth and --sun-elevation "
                             "or --sun-vector (grid frame: x image right, y image up, z up)")
    if view_vector is not None:
        view, view_source = view_vector, "--view"
    elif image.tag_json("view_vector_grid") is not None:
        view, view_source = image.tag_json("view_vector_grid"), \
            f"tag view_vector_grid of {image.path}"
    else:
        view, view_source = (0.0, 0.0, 1.0), "default (nadir)"
    try:
        make_illumination(sun)  # checks the sun alone, against a nadir view
    except ParameterError as exc:
        raise ParameterError(f"{sun_source}: {exc}") from None
    try:
        illumination = make_illumination(sun, view)
    except ParameterError as exc:
        raise ParameterError(f"{view_source}: {exc}") from None
    return illumination, {"sun": sun_source, "view": view_source}


def _is_unit_pixel_transform(transform) -> bool:
    return (transform.a, transform.b, transform.c, transform.d, transform.e, transform.f) == \
        (1.0, 0.0, 0.0, 0.0, -1.0, 0.0)


def image_on_dem_grid(image: Raster, dem: Raster) -> tuple[np.ndarray, str | None]:
    """The image's values on the DEM's grid, resampled if the grids differ.

    An image in its own pixel frame (unit transform, no CRS) and a DEM in an image
    frame (CONTRIBUTING.md) are the same grid when their shapes agree; with different
    shapes the image is taken to cover the DEM's extent.  Otherwise both transforms
    must be in the same map units (and CRS), and the image is resampled bilinearly
    (:func:`demtool.compare.grids.resample_to_grid`, NaN-aware).

    Returns
    -------
    values : (H, W) float32
        Image on the DEM grid, NaN outside the image.
    note : str or None
        What was done when resampling (for the log and the sidecar), None otherwise.

    Raises
    ------
    InputError
        Different CRSs, or grids that do not overlap.
    """
    import numpy as np
    from affine import Affine

    from demtool.compare.grids import Grid, resample_to_grid
    from demtool.errors import InputError, ProcessingError

    dem_shape = dem.data.shape
    if image.data.shape == dem_shape and image.transform == dem.transform:
        return image.data, None
    pixel_frame = (_is_unit_pixel_transform(image.transform) and image.crs is None
                   and dem.crs is None)
    if pixel_frame and image.data.shape == dem_shape:
        check_same_frame(image, dem, "give the image the DEM was computed for", "the DEM")
        return image.data, None
    if image.crs != dem.crs and image.crs is not None and dem.crs is not None:
        raise InputError(f"{image.path}: the image's CRS ({image.crs}) differs from the DEM's "
                         f"({dem.crs}); reproject one of them")
    source_transform = image.transform
    if pixel_frame:
        # an image in pixel units over the extent of an image-frame DEM
        height, width = image.data.shape
        sx = dem.transform.a * dem_shape[1] / width
        sy = dem.transform.e * dem_shape[0] / height
        if abs(abs(sx) / abs(sy) - abs(dem.transform.a) / abs(dem.transform.e)) > 0.02 * abs(
                sx / sy):
            raise InputError(f"{image.path}: image ({height} × {width} px) and DEM "
                             f"{dem.path} ({dem_shape[0]} × {dem_shape[1]}) have different "
                             "aspect ratios and the image has no map transform: their grids "
                             "cannot be matched")
        source_transform = Affine(sx, 0.0, dem.transform.c, 0.0, sy, dem.transform.f)
    try:
        values = resample_to_grid(image.data, Grid(image.data.shape, source_transform),
                                  Grid(dem_shape, dem.transform)).astype(np.float32)
    except ProcessingError:
        raise InputError(f"{image.path}: the image does not overlap the DEM {dem.path} "
                         "(compare their transforms); nothing to refine") from None
    note = (f"image {image.data.shape[0]} × {image.data.shape[1]} resampled onto the DEM grid "
            f"{dem_shape[0]} × {dem_shape[1]} ({100 * np.isfinite(values).mean():.1f}% "
            "covered)")
    return values, note
