"""Map projections on a body's reference sphere, and map x/y ↔ lon/lat ↔ XYZ.

``--projection`` of the map stages:

* ``equirectangular`` — equidistant cylindrical centred on the footprint: central
  meridian at the footprint's centre longitude, true scale along the parallel of its
  centre latitude (ISIS ``Equirectangular`` with ``CenterLongitude``/``CenterLatitude``;
  PROJ ``eqc`` with ``lon_0``, ``lat_ts``; latitude of origin 0, so y = R·φ).
* ``polar-stereographic`` — polar stereographic on the nearer pole (central meridian 0,
  as PROJ's ``IAU_2015:xxx30``/``xxx35``), with true scale at the footprint's centre
  latitude (EPSG method 9829, variant B) so the grid's spacing is metres on the ground
  where the data are.
* ``auto`` — polar stereographic when the footprint's centre is poleward of ±70°,
  equirectangular otherwise (ASP's and the LOLA/PGDA products' practice).

All are built with pyproj on the body's geographic CRS (:meth:`Body.geographic_crs`),
so the CRS's datum names the body (and :func:`~demtool.maps.bodies.body_from_crs`
finds it again after a GeoTIFF round trip).  Transforms use ``always_xy`` (longitude,
latitude order; x east, y north).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from demtool.maps.bodies import Body, to_pyproj_crs
from demtool.maps.frames import (
    lonlat_height_to_xyz,
    unit_vector,
    wrap_longitude,
    xyz_to_lonlat_height,
)

__all__ = [
    "POLAR_LATITUDE",
    "PROJECTIONS",
    "choose_projection",
    "crs_radius",
    "crs_surface",
    "footprint_center",
    "lonlat_to_map",
    "make_projection",
    "map_to_lonlat",
    "map_to_xyz",
    "projection_on",
    "xyz_to_map",
]

PROJECTIONS = ("auto", "equirectangular", "polar-stereographic")
POLAR_LATITUDE = 70.0


def footprint_center(lon_deg: np.ndarray, lat_deg: np.ndarray) -> tuple[float, float]:
    """Centre of a set of surface points: the direction of their mean unit vector.

    Works across the ±180° meridian and near the poles (no averaging of angles).

    Parameters
    ----------
    lon_deg, lat_deg : float arrays, degrees
        East-positive longitudes, planetocentric latitudes (NaN entries are ignored).

    Returns
    -------
    (lon_deg, lat_deg) : float
        Longitude in (−180, 180], latitude.
    """
    unit = unit_vector(np.ravel(lon_deg), np.ravel(lat_deg))
    unit = unit[np.isfinite(unit).all(axis=1)]
    if unit.size == 0:
        raise ValueError("footprint has no finite point")
    mean = unit.mean(axis=0)
    if np.linalg.norm(mean) < 1e-9:
        raise ValueError("footprint points are spread over the whole body; no centre")
    lon, lat, _ = xyz_to_lonlat_height(mean, radii=1.0)
    return float(lon), float(lat)


def projection_on(geodetic_crs: Any, kind: str, center_lon: float, center_lat: float,
                  name: str | None = None):
    """A projected CRS of one ``kind`` on a given geodetic CRS.

    Parameters
    ----------
    geodetic_crs : CRS-like
        The geographic CRS (datum, ellipsoid) the projection is built on.
    kind : {"equirectangular", "polar-stereographic"}
    center_lon, center_lat : float, degrees
        Footprint centre (see the module docstring for how each projection uses it).
    name : str, optional
        Name of the CRS.

    Returns
    -------
    pyproj.CRS
    """
    from pyproj.crs import ProjectedCRS
    from pyproj.crs.coordinate_operation import (
        EquidistantCylindricalConversion,
        PolarStereographicBConversion,
    )

    base = to_pyproj_crs(geodetic_crs)
    base = base.geodetic_crs or base
    label = base.name.split(" / ")[0]
    # one centre for one meridian: 180 and −180 (or 190 and −170) make one CRS, so grids of
    # the same ground given in 0…360 and in −180…180 compare as the same grid
    center_lon = float(wrap_longitude(center_lon))
    if kind == "equirectangular":
        conversion = EquidistantCylindricalConversion(
            latitude_first_parallel=float(center_lat), latitude_natural_origin=0.0,
            longitude_natural_origin=float(center_lon))
        default = (f"{label} / Equirectangular, clon = {center_lon:.6g}, "
                   f"lat_ts = {center_lat:.6g}")
    elif kind == "polar-stereographic":
        pole = 90.0 if center_lat >= 0 else -90.0
        standard = float(np.clip(center_lat, 1e-6, 90.0) if pole > 0 else
                         np.clip(center_lat, -90.0, -1e-6))
        conversion = PolarStereographicBConversion(latitude_standard_parallel=standard,
                                                   longitude_origin=0.0)
        default = (f"{label} / {'North' if pole > 0 else 'South'} Polar Stereographic, "
                   f"lat_ts = {standard:.6g}")
    else:
        raise ValueError(f"unknown projection {kind!r}: should be equirectangular or "
                         "polar-stereographic")
    return ProjectedCRS(conversion=conversion, geodetic_crs=base, name=name or default)


def make_projection(body: Body, kind: str, center_lon: float, center_lat: float):
    """A projection on ``body``'s reference sphere (see the module docstring).

    Parameters
    ----------
    body : Body
    kind : {"auto", "equirectangular", "polar-stereographic"}
        ``auto`` picks polar stereographic poleward of ±70° (``POLAR_LATITUDE``).
    center_lon, center_lat : float, degrees
        Footprint centre, planetocentric, east-positive.

    Returns
    -------
    pyproj.CRS
        A projected CRS whose geodetic CRS is :meth:`Body.geographic_crs`.
    """
    if kind not in PROJECTIONS:
        raise ValueError(f"unknown projection {kind!r}: should be one of "
                         + ", ".join(PROJECTIONS))
    if kind == "auto":
        kind = "polar-stereographic" if abs(center_lat) >= POLAR_LATITUDE else "equirectangular"
    return projection_on(body.geographic_crs(), kind, center_lon, center_lat)


def choose_projection(body: Body, lon_deg: np.ndarray, lat_deg: np.ndarray,
                      projection: str = "auto"):
    """The projection of a footprint: :func:`make_projection` at :func:`footprint_center`.

    Parameters
    ----------
    body : Body
    lon_deg, lat_deg : float arrays, degrees
        Footprint points (polygon vertices or ground points).
    projection : {"auto", "equirectangular", "polar-stereographic"}

    Returns
    -------
    pyproj.CRS
    """
    center_lon, center_lat = footprint_center(lon_deg, lat_deg)
    return make_projection(body, projection, center_lon, center_lat)


@functools.lru_cache(maxsize=64)
def _transformers(wkt: str):
    from pyproj import CRS, Transformer

    crs = CRS.from_wkt(wkt)
    geographic = crs.geodetic_crs or crs
    forward = Transformer.from_crs(geographic, crs, always_xy=True)
    inverse = Transformer.from_crs(crs, geographic, always_xy=True)
    return forward, inverse


def _transformer_pair(crs: Any):
    return _transformers(to_pyproj_crs(crs).to_wkt())


def lonlat_to_map(crs: Any, lon_deg: np.ndarray, lat_deg: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates of longitudes and latitudes of the CRS's own geodetic CRS.

    Parameters
    ----------
    crs : CRS-like
        A projected CRS (or a geographic one: then x = lon, y = lat).
    lon_deg, lat_deg : float arrays, degrees
        Planetocentric, east-positive on demtool's sphere CRSs.

    Returns
    -------
    x, y : float64 arrays, map units (metres for a projected CRS)
        ``inf`` where the projection is undefined.
    """
    forward, _ = _transformer_pair(crs)
    x, y = forward.transform(np.asarray(lon_deg, dtype=np.float64),
                             np.asarray(lat_deg, dtype=np.float64))
    return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)


def map_to_lonlat(crs: Any, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Longitudes and latitudes (degrees, the CRS's geodetic CRS) of map coordinates."""
    _, inverse = _transformer_pair(crs)
    lon, lat = inverse.transform(np.asarray(x, dtype=np.float64),
                                 np.asarray(y, dtype=np.float64))
    return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)


def crs_radius(crs: Any) -> float:
    """Radius of the sphere a CRS is on, metres.

    Raises
    ------
    ValueError
        When the CRS's ellipsoid is not a sphere (its latitudes would not be
        planetocentric; demtool's maps are on the reference sphere).
    """
    pcrs = to_pyproj_crs(crs)
    ellipsoid = (pcrs.geodetic_crs or pcrs).ellipsoid
    a, b = ellipsoid.semi_major_metre, ellipsoid.semi_minor_metre
    if not np.isclose(a, b, rtol=1e-12, atol=0.0):
        raise ValueError(f"CRS {pcrs.name!r} is on an ellipsoid (a={a:.10g}, b={b:.10g} m), "
                         "not on a sphere")
    return float(a)


def crs_surface(crs: Any):
    """The surface a CRS measures heights from, as a ``radii`` argument of
    :func:`~demtool.maps.frames.lonlat_height_to_xyz`: its sphere's radius (metres), or
    a :class:`~demtool.maps.frames.GeodeticEllipsoid` for a CRS on an ellipsoid of
    revolution (EPSG:4326, UTM: geodetic latitude, height along the normal)."""
    from demtool.maps.frames import GeodeticEllipsoid

    pcrs = to_pyproj_crs(crs)
    ellipsoid = (pcrs.geodetic_crs or pcrs).ellipsoid
    a, c = ellipsoid.semi_major_metre, ellipsoid.semi_minor_metre
    if np.isclose(a, c, rtol=1e-12, atol=0.0):
        return float(a)
    return GeodeticEllipsoid(float(a), float(c))


def map_to_xyz(crs: Any, x: np.ndarray, y: np.ndarray, height: np.ndarray | float = 0.0
               ) -> np.ndarray:
    """Body-fixed XYZ of map coordinates raised by heights above the CRS's surface.

    Parameters
    ----------
    crs : CRS-like
        On a sphere (heights radial) or an ellipsoid (heights along the normal,
        :func:`crs_surface`).
    x, y : float arrays, map units
    height : float array, metres above the surface (broadcastable)

    Returns
    -------
    (..., 3) float64, metres
    """
    lon, lat = map_to_lonlat(crs, x, y)
    return lonlat_height_to_xyz(lon, lat, height, radii=crs_surface(crs))


def xyz_to_map(crs: Any, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map coordinates and height above the CRS's surface of body-fixed points.

    Parameters
    ----------
    crs : CRS-like, on a sphere or an ellipsoid (:func:`crs_surface`)
    xyz : (..., 3) float, metres

    Returns
    -------
    x, y : (...) float64, map units
    height : (...) float64, metres above the surface
    """
    lon, lat, height = xyz_to_lonlat_height(xyz, radii=crs_surface(crs))
    x, y = lonlat_to_map(crs, lon, lat)
    return x, y, height
