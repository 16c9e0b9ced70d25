"""What the ``dem`` routes read, untiled and tiled alike: the disparity with its
rectification, the sensor models a calibrated ``rectify.npz`` carries, and the
orthoimages of the map-projected route with the geometry their tags name.

Used by the runners (:mod:`demtool.dem.run`, :mod:`demtool.dem.run_sensors`,
:mod:`demtool.dem.run_mapprojected`) and by the tiled jobs (:mod:`demtool.dem.tiled_map`),
so that no tiled job imports a runner.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from demtool.sensors.base import SensorModel


def read_disparity(disparity_path: str | os.PathLike, rectify_path: str | os.PathLike,
                   rectification: dict, size_rect, log) -> Any:
    """The disparity raster of a rectified pair, checked against its rectification.

    Refuses a disparity that is not on the rectified canvas ``size_rect`` (width,
    height); masks values far outside the range the disparity was searched over (logged
    with their count) and refuses a file where most are (see
    :func:`demtool.imaging.checks.check_disparity_range`).  That range is the rectification's
    ``disparity_range`` joined with what sgm searched, widenings included (its tags
    ``min_disparity``/``num_disparities``): what sgm found is what dem accepts.  Returns
    the ``io.Raster`` with the masked values.
    """
    import dataclasses

    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.imaging.checks import check_disparity_range

    disparity = dio.read_raster(disparity_path, what="disparity")
    width_rect, height_rect = (int(v) for v in size_rect)
    if disparity.data.shape != (height_rect, width_rect):
        raise InputError(f"{disparity_path}: disparity is {disparity.data.shape[1]}×"
                         f"{disparity.data.shape[0]} px but {rectify_path} has a "
                         f"{width_rect}×{height_rect} rectified canvas")
    searched = searched_range(disparity.tags)
    accepted = [float(v) for v in rectification["disparity_range"]]
    source = f"{rectify_path}"
    if searched is not None:
        accepted = [min(accepted[0], searched[0]), max(accepted[1], searched[1])]
        source = f"{rectify_path} and the range sgm searched ({searched[0]:g} … {searched[1]:g})"
    checked = check_disparity_range(disparity.data, accepted, disparity_path, source=source)
    if checked.outside:
        log.warning("%s: %d disparities outside %.4g … %.4g px masked", disparity_path,
                    checked.outside, checked.low, checked.high)
    return dataclasses.replace(disparity, data=checked.disparity)


def searched_range(tags: dict) -> tuple[float, float] | None:
    """(min, max) disparity a matcher searched, from a disparity raster's tags
    (``min_disparity``, ``num_disparities`` written by sgm), or None."""
    import math

    try:
        low = float(tags["min_disparity"])
        count = float(tags["num_disparities"])
    except (KeyError, TypeError, ValueError):
        return None
    if not (math.isfinite(low) and math.isfinite(count)) or count < 1:
        return None
    return low, low + count - 1


def pair_names(disparity_path, rectify_path, rectification: dict, frame: str,
               target: str | None) -> tuple[str, str, str, str]:
    """(left name, right name, target name, target side) of a disparity's pair, checked:
    the disparity's frame must be the rectification's left rectified image, and the
    target (default the left image) one of the pair (InputError otherwise)."""
    from demtool.errors import InputError

    left_name = str(rectification["left_name"])
    right_name = str(rectification["right_name"])
    if frame.startswith("image:") and frame != f"image:{left_name}_rect":
        raise InputError(f"{disparity_path}: disparity in frame {frame}, but {rectify_path} "
                         f"rectifies {left_name} (image:{left_name}_rect); is it the "
                         "rectification of this pair?")
    target_name = target or left_name
    if target_name not in (left_name, right_name):
        raise InputError(f"{rectify_path}: target {target_name} is neither the left "
                         f"({left_name}) nor the right ({right_name}) image of the pair")
    return left_name, right_name, target_name, "left" if target_name == left_name else "right"


def check_pair_cameras(cameras: dict, cameras_path, rectify_path, rectification: dict,
                       left_name: str, right_name: str) -> None:
    """InputError unless ``cameras`` (read from ``cameras_path``: a cameras.npz or a
    bundle.npz) has both images of the pair at the sizes the rectification says."""
    from demtool.errors import InputError

    missing = [n for n in (left_name, right_name) if n not in cameras]
    if missing:
        raise InputError(f"{cameras_path}: no camera for {', '.join(missing)} (the images "
                         f"{rectify_path} rectifies)")
    for name, side_name in ((left_name, "left"), (right_name, "right")):
        size = tuple(int(v) for v in rectification[f"size_{side_name}"])
        if (cameras[name].width, cameras[name].height) != size:
            raise InputError(f"{cameras_path}: camera {name} is {cameras[name].width}×"
                             f"{cameras[name].height} px but {rectify_path} says the "
                             f"{side_name} image is {size[0]}×{size[1]}")


def is_calibrated(rectification: dict) -> bool:
    """True for a rectify.npz written with sensor models."""
    return "calibrated" in rectification and bool(rectification["calibrated"])


def rectifying_right_model(rectification: dict, right, rectify_path):
    """The right model that resampled the pair: ``rectifying_right_*`` when rectify fitted a
    pose to the matches for the rectification only (:mod:`demtool.rectify.relative_pose`),
    else ``right`` (the triangulating model)."""
    from demtool.errors import InputError
    from demtool.sensors.arrays import model_from_arrays

    if "rectifying_right_type" not in rectification:
        return right
    try:
        return model_from_arrays(rectification, "rectifying_right_")
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{rectify_path}: bad rectifying right model ({exc})") from None


def models_from_rectification(rectification: dict, rectify_path
                              ) -> tuple[SensorModel, SensorModel]:
    """The left and right models stored in a calibrated rectify.npz (InputError naming the
    missing key)."""
    from demtool.errors import InputError
    from demtool.sensors.arrays import model_from_arrays

    models = []
    for side in ("left", "right"):
        try:
            models.append(model_from_arrays(rectification, f"sensor_{side}_"))
        except KeyError as exc:
            raise InputError(f"{rectify_path}: calibrated rectification file lacks the key "
                             f"{exc.args[0]!r}") from None
        except (ValueError, TypeError) as exc:
            raise InputError(f"{rectify_path}: bad {side} sensor model ({exc})") from None
    from demtool.sensors.validate import check_model

    for side, model in zip(("left", "right"), models, strict=True):  # issue 31: the file
        check_model(model, rectify_path, f"rectify_{side}")  # is blamed, not the disparity
    return models[0], models[1]


def geometry_from_rectification(rectification: dict, left, right):
    """The :class:`~demtool.rectify.calibrated.RectifiedGeometry` stored in rectify.npz;
    ``right`` is the model that rectified (:func:`rectifying_right_model`)."""
    import numpy as np

    from demtool.rectify.calibrated import RectifiedGeometry

    K_left, K_right = rectification["K_left_rect"], rectification["K_right_rect"]
    centers = np.stack([left.camera_center(0.5 * left.lines),
                        right.camera_center(0.5 * right.lines)])
    return RectifiedGeometry(R_rect=np.asarray(rectification["R_rect"], dtype=np.float64),
                             f_px=float(K_left[0, 0]), cx_left=float(K_left[0, 2]),
                             cx_right=float(K_right[0, 2]), cy=float(K_left[1, 2]),
                             size_rect=np.asarray(rectification["size_rect"]), centers=centers)


class Ortho(NamedTuple):
    """An orthoimage's grid, sensor model and surface (heights at map x, y)."""

    info: Any
    sensor: Any
    heights: Any  # callable (x, y) -> heights above the body's sphere, metres
    surface: str


def read_ortho(path, *, what: str) -> Ortho:
    """Read an orthoimage's tags: its sensor model and the surface it was projected on.

    Raises InputError (one line naming the file) when it has no mapproject tags, its
    sensor file or DEM is missing, or it is not on a projected map.
    """
    from pathlib import Path

    import numpy as np

    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.surface import (
        DEM_TAG,
        HEIGHT_TAG,
        SENSOR_TAG,
        SURFACE_TAG,
        read_dem_surface,
    )
    from demtool.maps import map_to_lonlat, to_pyproj_crs
    from demtool.sensors import read_sensor
    from demtool.sensors.isis_cam2map import is_cam2map_cube
    from demtool.sensors.isis_map import refuse_cam2map_ortho

    if is_cam2map_cube(path):  # an ISIS cam2map cube: its camera and map from the cube
        return _cam2map_ortho(path, what)
    refuse_cam2map_ortho(path, what)  # an ISIS cube of another kind: say what it lacks
    info = dio.raster_info(path, what=what)
    tags = info.tags
    if SENSOR_TAG not in tags or SURFACE_TAG not in tags:
        raise InputError(f"{path}: {what} has no sensor tags ({SENSOR_TAG}, {SURFACE_TAG}); "
                         "give orthoimages written by demtool mapproject")
    sensor_path = Path(tags[SENSOR_TAG])
    if not sensor_path.is_file():
        raise InputError(f"{path}: its sensor model {sensor_path} (tag {SENSOR_TAG}) is "
                         "missing")
    if info.crs is None or not to_pyproj_crs(info.crs).is_projected:
        raise InputError(f"{path}: {what} is not on a projected map of the body")
    from demtool.mapproject.hashes import check_hashes

    check_hashes(path, tags)
    from demtool.mapproject.tsai_body import ortho_sensor

    sensor = ortho_sensor(read_sensor(sensor_path), sensor_path, info.crs,
                          info.tag_json("image_size"))
    crs = to_pyproj_crs(info.crs)
    if tags[SURFACE_TAG] == "height" and HEIGHT_TAG in tags:
        try:
            height = float(tags[HEIGHT_TAG])
        except ValueError:
            raise InputError(f"{path}: tag {HEIGHT_TAG}={tags[HEIGHT_TAG]!r} is not a "
                             "number") from None

        def heights(x, y):
            return np.full(np.shape(x), height)
    elif tags[SURFACE_TAG] == "dem" and DEM_TAG in tags:
        dem_path = Path(tags[DEM_TAG])
        if not dem_path.is_file():
            raise InputError(f"{path}: the DEM it was projected on, {dem_path} (tag "
                             f"{DEM_TAG}), is missing")
        surface = read_dem_surface(dem_path, sensor_path, sensor_body(sensor))
        same = not surface.geographic and to_pyproj_crs(surface.info.crs) == crs

        def heights(x, y):
            if same:
                return surface.heights_xy(x, y)
            return surface.heights_lonlat(*map_to_lonlat(crs, x, y))
    else:
        raise InputError(f"{path}: tag {SURFACE_TAG}={tags[SURFACE_TAG]!r} without its "
                         f"{DEM_TAG} or {HEIGHT_TAG}")
    return Ortho(info, sensor, heights, tags[SURFACE_TAG])


def _cam2map_ortho(path, what: str) -> Ortho:
    """An ISIS ``cam2map`` cube as an :class:`Ortho`: the raw camera from the cube's own
    tables, the surface the label's ellipsoid (:mod:`demtool.sensors.isis_cam2map`)."""
    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.maps import to_pyproj_crs
    from demtool.sensors.isis_cam2map import cam2map_camera, cam2map_surface

    sensor = cam2map_camera(path)  # first: a camera demtool cannot read says so
    info = dio.raster_info(path, what=what)
    if info.crs is None or not to_pyproj_crs(info.crs).is_projected:
        raise InputError(f"{path}: {what} is not on a projected map of the body")
    heights, surface = cam2map_surface(path, to_pyproj_crs(info.crs))
    return Ortho(info, sensor, heights, surface)
