"""ISIS map-projected image cubes (``cam2map``) as orthoimages of the map-projected stereo
route (``sgm`` and ``dem --mapprojected`` on two cubes of one grid).

A ``cam2map`` cube keeps its camera's SPICE tables and ``NaifKeywords`` and its
``AlphaCube`` (the raw image's window), so the raw camera is read from the cube itself
(:func:`demtool.sensors.isis_linescan.read_linescan_cube` with ``mapped=True``); GDAL's
ISIS3 driver gives the map grid (for a planetocentric ellipsoid it writes a sphere of the
ellipsoid's radius at the projection's centre latitude).

The surface the pixels were projected on is ``cam2map``'s shape model, named in the
``Kernels`` group's ``ShapeModel`` (a DEM such as MOLA's radius cube, or ``Null`` for the
ellipsoid); the cube does not carry it.  :func:`cam2map_surface` takes the ellipsoid of
the ``Mapping`` group (``EquatorialRadius``, ``PolarRadius``, planetocentric latitude) as
that surface and says so: where ``cam2map`` used a DEM, the DEM's height above the
ellipsoid is a near-constant offset of the result over a small map (ASP's
``cam2map4stereo.py`` pairs), and the raw coordinates move by that offset times the
tangent of the view's off-nadir angle.  The description goes into the DEM's provenance.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def is_cam2map_cube(path) -> bool:
    """True when ``path`` is an ISIS cube with a ``Mapping`` group whose ``Instrument``
    group names a line-scan camera (``LineExposureDuration``): an image map-projected
    by ``cam2map`` whose camera demtool can read from the cube."""
    from demtool.sensors.isis_map import read_cube_label

    if path is None:
        return False
    try:
        label = read_cube_label(path)
    except Exception:  # noqa: BLE001 - unreadable labels are left to the readers
        return False
    if label is None:
        return False
    cube = label["IsisCube"]
    return "Mapping" in cube and "LineExposureDuration" in cube.get("Instrument", {})


def _meters(value) -> float:
    number = float(getattr(value, "value", value))
    unit = str(getattr(value, "units", "") or "meters").lower()
    return number * 1000.0 if unit in ("km", "kilometers") else number


def cam2map_surface(path, crs) -> tuple[Any, str]:
    """The surface a ``cam2map`` cube was projected on, as heights above ``crs``'s sphere.

    Returns
    -------
    heights : callable (x, y) -> float64 array
        Metres above the CRS's sphere of the label's ellipsoid at map (x, y).
    surface : str
        What was assumed, for the log and the provenance.

    Raises
    ------
    InputError
        The Mapping group lacks the radii, or its latitudes are not planetocentric.
    """
    from demtool.errors import InputError
    from demtool.maps import map_to_lonlat
    from demtool.maps.projections import crs_radius
    from demtool.sensors.isis_map import read_cube_label

    label = read_cube_label(path)
    cube = label["IsisCube"]
    mapping = cube["Mapping"]
    try:
        a = _meters(mapping["EquatorialRadius"])
        b = _meters(mapping["PolarRadius"])
    except KeyError as exc:
        raise InputError(f"{path}: the Mapping group lacks the key {exc}") from None
    kind = str(mapping.get("LatitudeType", "Planetocentric"))
    if kind.lower() != "planetocentric":
        raise InputError(f"{path}: the Mapping group's LatitudeType is {kind}; demtool's "
                         "map-projected route reads planetocentric maps")
    radius = crs_radius(crs)
    radius = float(np.atleast_1d(radius)[0])

    def heights(x, y):
        _, lat = map_to_lonlat(crs, np.asarray(x, dtype=np.float64),
                               np.asarray(y, dtype=np.float64))
        phi = np.radians(lat)
        r = a * b / np.sqrt((b * np.cos(phi)) ** 2 + (a * np.sin(phi)) ** 2)
        return r - radius

    shape = str(cube.get("Kernels", {}).get("ShapeModel", "Null"))
    surface = (f"isis-ellipsoid: the Mapping group's ellipsoid ({a:.1f}, {b:.1f} m); "
               f"cam2map's shape model {Path(shape).name} is not in the cube, heights are "
               "relative to the ellipsoid" if shape.lower() not in ("null", "")
               else f"isis-ellipsoid: cam2map's ellipsoid ({a:.1f}, {b:.1f} m)")
    return heights, surface


def cam2map_camera(path):
    """The raw line-scan camera a ``cam2map`` cube keeps (see module docstring)."""
    from demtool.sensors.isis_linescan import read_linescan_cube

    return read_linescan_cube(path, mapped=True)


def parallax_precision(left, right, xyz) -> dict[str, float]:
    """What a pair's geometry allows at a ground point: the convergence angle between
    the two views (degrees), and the height change per pixel of map parallax (metres),
    ``GSD / (tan e_l ± tan e_r)`` along the parallax direction, estimated here as
    ``GSD_ground / (2 tan(γ / 2))`` with γ the convergence (the symmetric case).

    Parameters
    ----------
    left, right : SensorModel
    xyz : (3,) float, body-fixed metres
    """
    point = np.asarray(xyz, dtype=np.float64).reshape(1, 3)
    views = []
    for model in (left, right):
        line, _ = model.ground_to_image(point)
        centre = model.camera_center(line)[0]
        views.append((centre - point[0]) / np.linalg.norm(centre - point[0]))
    gamma = float(np.degrees(np.arccos(np.clip(views[0] @ views[1], -1.0, 1.0))))
    return {"convergence_deg": gamma,
            "height_per_px_parallax_factor": float(1.0 / (2.0 * np.tan(np.radians(gamma) / 2)))}
