"""Checks of a map-projection grid before any work (issue 31, class 3): its size against
the memory budget and the free disk, its oversampling of the image, and ``--bounds``
against the image's footprint (longitudes compared modulo 360°, so 0…360 and −180…180
bounds name the same ground)."""

from __future__ import annotations

from typing import Any

import numpy as np

from demtool.errors import ParameterError
from demtool.maps.frames import longitude_span, wrap_longitude

#: map cells per image pixel beyond which a grid is refused: a GSD 100 × finer than the
#: image's own (nothing to gain, hours and terabytes to lose)
MAX_CELLS_PER_PIXEL = 1e4
#: bytes per map cell the in-process loop holds at once is bounded by its tiles; the file
#: holds 4 bytes per cell and band
FILE_BYTES_PER_CELL = 4


def footprint_box(lon, lat) -> tuple[float, float, float, float]:
    """``(lon_min, lat_min, lon_max, lat_max)`` of points, longitudes unwrapped about their
    circular mean (a footprint across the antimeridian stays one box)."""
    lon = np.asarray(lon, dtype=np.float64)
    lat = np.asarray(lat, dtype=np.float64)
    rad = np.radians(lon)
    centre = float(np.degrees(np.arctan2(np.sin(rad).mean(), np.cos(rad).mean())))
    unwrapped = wrap_longitude(lon, centre)
    return (float(unwrapped.min()), float(lat.min()), float(unwrapped.max()), float(lat.max()))


def bounds_overlap(bounds, box) -> bool:
    """Whether ``--bounds`` and a footprint box (both lon/lat degrees) share ground."""
    lon0, lat0, lon1, lat1 = (float(v) for v in bounds)
    lon0, lon1 = longitude_span(lon0, lon1)
    f_lon0, f_lat0, f_lon1, f_lat1 = box
    if lat1 < f_lat0 or lat0 > f_lat1:
        return False
    if lon1 - lon0 >= 360.0:
        return True
    centre = 0.5 * (f_lon0 + f_lon1)
    shift = float(wrap_longitude(0.5 * (lon0 + lon1), centre)) - 0.5 * (lon0 + lon1)
    lon0, lon1 = lon0 + shift, lon1 + shift
    return not (lon1 < f_lon0 or lon0 > f_lon1)


def grid_option(params: Any, dem_path: Any) -> str:
    """The option that set the grid's spacing and extent (named in the errors)."""
    if params.gsd is not None:
        return "--gsd"
    if params.bounds is not None:
        return "--bounds"
    if dem_path is not None:
        return "--dem"
    return "the image's own GSD (--gsd)"


def check_mapproject_grid(sensor: Any, body: Any, grid: Any, params: Any, *, dem_path: Any,
                          out_path: Any, bands: int, log=None) -> None:
    """Refuse, before any work, a grid that is too big or that does not see the image.

    Raises
    ------
    ParameterError
        ``--bounds`` away from the footprint (lon/lat of both in the message); more than
        :data:`MAX_CELLS_PER_PIXEL` map cells per image pixel; an output larger than the
        free disk — each naming the option that made the grid so.
    """
    from demtool import sizes
    from demtool.mapproject.core import ground_footprint
    from demtool.maps import xyz_to_lonlat_height

    option = grid_option(params, dem_path)
    height = params.height if params.height is not None else 0.0
    nbytes = int(grid.height) * int(grid.width) * FILE_BYTES_PER_CELL * bands
    if log is not None:
        log.info("orthoimage grid: %d x %d cells (%s on disk)", grid.width, grid.height,
                 sizes.human_bytes(nbytes))
    if params.bounds is not None:
        xyz = ground_footprint(sensor, body.surface, height)
        seen = np.isfinite(xyz).all(axis=1)
        if seen.any():
            lon, lat, _ = xyz_to_lonlat_height(xyz[seen], radii=body.surface)
            box = footprint_box(lon, lat)
            if not bounds_overlap(params.bounds, box):
                raise ParameterError(
                    "--bounds: lon {:g}…{:g}, lat {:g}…{:g} does not overlap the image's "
                    "footprint (lon {:.4g}…{:.4g}, lat {:.4g}…{:.4g}): nothing of the image "
                    "would be on the map".format(*np.asarray(params.bounds)[[0, 2, 1, 3]],
                                                 box[0], box[2], box[1], box[3]))
    pixels = max(1, int(sensor.lines) * int(sensor.samples))
    ratio = grid.height * grid.width / pixels
    if ratio > MAX_CELLS_PER_PIXEL:
        raise ParameterError(f"{option}: the orthoimage would be {grid.width} x {grid.height} "
                             f"cells ({sizes.human_bytes(nbytes)}), {ratio:.3g} cells per "
                             f"pixel of the {sensor.samples} x {sensor.lines} image; choose a "
                             f"coarser {option} or a smaller area")
    sizes.check_disk(out_path, nbytes, what="orthoimage", option=option)


#: |height| above the reference sphere a DEM may hold: this fraction of the body's radius
#: (Vesta's relief is 15 % of its radius, small bodies' more), at least 30 km (Olympus Mons
#: is 22 km high)
MAX_HEIGHT_FRACTION, MIN_HEIGHT_LIMIT_M = 0.5, 30e3


def height_limit(body: Any) -> float:
    """Largest plausible |height| (metres) above ``body``'s reference sphere."""
    return max(MIN_HEIGHT_LIMIT_M, MAX_HEIGHT_FRACTION * float(body.radius))


def check_surface_heights(found, dem_path: Any, body: Any) -> None:
    """Refuse a DEM whose heights under the image's footprint cannot be heights above the
    body's sphere: none valid (all NaN, nodata, or the DEM elsewhere), or beyond
    :func:`height_limit` (1e27 fill values, radii of another body; radii of this body are
    read as heights by :func:`demtool.mapproject.surface.read_dem_surface`) — naming the
    DEM, not the image."""
    from demtool.errors import InputError

    found = np.asarray(found, dtype=np.float64)
    finite = found[np.isfinite(found)]
    if finite.size == 0:
        raise InputError(f"{dem_path}: DEM has no valid height under the image's footprint "
                         "(all NaN or nodata there, or it covers other ground)")
    limit = height_limit(body)
    worst = float(np.max(np.abs(finite)))
    if worst > limit:
        raise InputError(f"{dem_path}: DEM heights reach {worst:.4g} m under the image's "
                         f"footprint, beyond ±{limit:.4g} m of {body.name}'s reference sphere "
                         f"(radius {body.radius:.7g} m): a fill value, or a DEM of another "
                         "body?")


def check_rpc_domain(sensor: Any, body: Any, heights: Any, what: str) -> None:
    """Refuse ground an RPC model is not valid for (:meth:`RpcSensor.domain_problem`):
    the image's footprint at ``heights`` (the ``--height``, or the DEM's heights under
    it), which must lie in the RPC's lon/lat/height domain.  ``what`` names the input
    (``--height 9000``, the DEM's path).  Models without a domain pass."""
    from demtool.errors import InputError
    from demtool.mapproject.core import ground_footprint
    from demtool.maps import xyz_to_lonlat_height

    if not hasattr(sensor, "domain_problem"):
        return
    heights = np.asarray(heights, dtype=np.float64)
    problem = sensor.domain_problem(np.nan, np.nan, heights)
    if problem is None:
        with np.errstate(invalid="ignore"):
            xyz = ground_footprint(sensor, body.surface, np.nanmedian(heights))
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=body.surface)
        problem = sensor.domain_problem(lon, lat, heights)
    if problem is not None:
        error = ParameterError if what.startswith("--") else InputError
        raise error(f"{what}: {problem} of the sensor model {sensor.name or 'RPC'}")


def check_height(sensor: Any, body: Any, height: float) -> None:
    """Refuse a ``--height`` no surface can have: beyond :func:`height_limit`, above
    the camera, or outside an RPC's validity domain."""
    check_rpc_domain(sensor, body, height, f"--height {height:g}")
    limit = height_limit(body)
    if abs(height) > limit:
        raise ParameterError(f"--height {height:g}: beyond ±{limit:.4g} m of {body.name}'s "
                             f"reference sphere (radius {body.radius:.7g} m); heights are "
                             "metres above the sphere")
    try:
        centre = np.asarray(sensor.camera_center(np.array([0.5 * sensor.lines])),
                            dtype=np.float64).reshape(-1, 3)[0]
    except (AttributeError, ValueError):
        return
    altitude = float(np.linalg.norm(centre)) - float(body.radius)
    if np.isfinite(altitude) and height >= altitude:
        raise ParameterError(f"--height {height:g}: at or above the camera ({altitude:.6g} m "
                             "above the sphere)")


def model_footprint_box(sensor: Any, radius: Any) -> tuple[float, float, float, float] | None:
    """Lon/lat box (degrees) of a model's footprint on the sphere of ``radius`` or the
    geodetic ellipsoid (a body's :attr:`~demtool.maps.Body.surface`; None when no edge
    point sees it)."""
    from demtool.mapproject.core import ground_footprint
    from demtool.maps import xyz_to_lonlat_height

    xyz = ground_footprint(sensor, radius, 0.0)
    seen = np.isfinite(xyz).all(axis=1)
    if not seen.any():
        return None
    lon, lat, _ = xyz_to_lonlat_height(xyz[seen], radii=radius)
    return footprint_box(lon, lat)


#: footprints farther apart than this many footprint diagonals are not one stereo pair
NOT_A_PAIR_SIZES = 3.0


def check_pair_overlaps(left: Any, right: Any, left_path: Any, right_path: Any) -> None:
    """Refuse a stereo pair of body-fixed models whose footprints share no ground (a pair
    1 800 km apart is not a pointing error for ``bundle`` to fix)."""
    from demtool.errors import InputError

    if left.radii is None or right.radii is None:
        return
    from demtool.mapproject.core import sensor_body

    radius = float(left.radii[0])
    surface = sensor_body(left).surface if getattr(left, "height_reference", "") == \
        "ellipsoid" else radius
    boxes = model_footprint_box(left, surface), model_footprint_box(right, surface)
    if boxes[0] is None or boxes[1] is None or bounds_overlap(boxes[1], boxes[0]):
        return
    with np.errstate(all="ignore"):
        centres = [m.image_to_ground(0.5 * m.lines, 0.5 * m.samples) for m in (left, right)]
    distance = float(np.linalg.norm(np.asarray(centres[0]) - np.asarray(centres[1])))
    # footprints a few of their own sizes apart may still be one pair whose SPICE is off
    # (the matches then say so, and bundle fixes it); farther apart they are not a pair
    size = max(np.hypot((b[2] - b[0]) * np.cos(np.radians(0.5 * (b[1] + b[3]))), b[3] - b[1])
               for b in boxes) * np.pi / 180.0 * radius
    if not np.isfinite(distance) or distance < NOT_A_PAIR_SIZES * size:
        return

    def box(b):
        return f"lon {b[0]:.4g}…{b[2]:.4g}, lat {b[1]:.4g}…{b[3]:.4g}"

    raise InputError(f"{right_path}: its footprint ({box(boxes[1])}) does not overlap that of "
                     f"{left_path} ({box(boxes[0])}; centres {distance / 1e3:.4g} km apart): "
                     "not a stereo pair")
