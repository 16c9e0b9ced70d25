"""Planetocentric coordinates ↔ body-fixed XYZ, and local east-north-up frames.

Body-fixed frame: the body's IAU rotating frame (``IAU_MOON``, ``IAU_MARS``, or the
frame a sensor model's ephemeris is in), origin at the centre of mass, +Z the north
pole, +X the prime meridian, metres.  Latitudes are **planetocentric** (the angle
between the equator and the radius vector) and longitudes **east-positive**, in degrees,
as in the IAU 2015 ``+0`` CRSs and ISIS's ``Ocentric``/``PositiveEast`` mapping.

Heights are measured **radially** (along the radius vector), as ISIS does with its
local radius: a point at latitude φ, longitude λ and height h above a reference
surface of radius r_ref(φ, λ) in that direction is at distance r_ref + h from the
centre.  For the reference sphere r_ref = R; for a triaxial ellipsoid
r_ref = (u_x²/a² + u_y²/b² + u_z²/c²)^(-1/2) with u the unit radius vector
(ISIS ``TriaxialEllipsoid``'s local radius; Archinal et al. 2018, Celest. Mech. Dyn.
Astron. 130:22, sec. 3).

Earth's products (RPC models, UTM maps) measure heights differently: **geodetic**
latitude (the angle of the ellipsoid's normal) and height along that normal above an
ellipsoid of revolution (WGS 84).  A :class:`GeodeticEllipsoid` passed as ``radii``
selects that convention in :func:`lonlat_height_to_xyz` and :func:`xyz_to_lonlat_height`
(the body's :attr:`~demtool.maps.Body.surface` says which one a map uses).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "GeodeticEllipsoid",
    "enu_frame",
    "local_radius",
    "lonlat_height_to_xyz",
    "unit_vector",
    "longitude_span",
    "wrap_longitude",
    "xyz_to_lonlat_height",
]


class GeodeticEllipsoid(NamedTuple):
    """An ellipsoid of revolution whose points are given by geodetic latitude and height
    along the normal (WGS 84: ``GeodeticEllipsoid(6378137.0, 6356752.314245179)``).

    Attributes
    ----------
    a, c : float
        Equatorial and polar semi-axes, metres.
    """

    a: float
    c: float


#: The WGS 84 ellipsoid (EPSG:7030), heights of RPC models and Earth maps.
WGS84_ELLIPSOID = GeodeticEllipsoid(6378137.0, 6356752.314245179)


def geodetic_to_xyz(lon_deg, lat_deg, height, ellipsoid: GeodeticEllipsoid) -> np.ndarray:
    """Body-fixed XYZ (metres, S + (3,)) of geodetic lon/lat (degrees) and height
    (metres along the normal): ``((N + h) cos φ cos λ, (N + h) cos φ sin λ,
    (N (1 − e²) + h) sin φ)`` with ``N = a / sqrt(1 − e² sin² φ)``."""
    a, c = float(ellipsoid[0]), float(ellipsoid[1])
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    e2 = 1.0 - (c * c) / (a * a)
    n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    lon, lat, n, h = np.broadcast_arrays(lon, lat, n, np.asarray(height, dtype=np.float64))
    return np.stack([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - e2) + h) * np.sin(lat)], axis=-1)


def xyz_to_geodetic(xyz, ellipsoid: GeodeticEllipsoid
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geodetic lon, lat (degrees) and height (metres) of body-fixed XYZ (Bowring's
    iteration, converged to 1e-12 rad in a few steps)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    a, c = float(ellipsoid[0]), float(ellipsoid[1])
    e2 = 1.0 - (c * c) / (a * a)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    with np.errstate(invalid="ignore", divide="ignore"):
        lat = np.arctan2(z, p * (1.0 - e2))
        for _ in range(6):
            n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
            height = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.cos(lat) - n, np.abs(z) - c)
            lat = np.arctan2(z, p * (1.0 - e2 * n / (n + height)))
        n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        height = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.cos(lat) - n, np.abs(z) - c)
    return np.degrees(np.arctan2(y, x)), np.degrees(lat), height


def wrap_longitude(lon_deg: np.ndarray | float, center: float = 0.0) -> np.ndarray:
    """Longitudes wrapped into [center − 180, center + 180), degrees.

    The one longitude rule of demtool: grids and points in −180…180, in 0…360 and across
    the antimeridian meet by moving longitudes by multiples of 360° next to a centre
    (``compare``'s overlap and resampling, ``mapproject``'s bounds and DEM lookups, the
    body-map DEM's projection centre).
    """
    lon = np.asarray(lon_deg, dtype=np.float64)
    return (lon - center + 180.0) % 360.0 - 180.0 + center


def longitude_span(lon_min: float, lon_max: float) -> tuple[float, float]:
    """A longitude interval, east from ``lon_min`` to ``lon_max``, degrees.

    ``lon_max < lon_min`` names a box across the antimeridian (as GDAL's and PROJ's
    bounding boxes do: 179.9 … −179.9 is 0.2° wide), returned with ``lon_max + 360`` so
    that ``lon_min < lon_max`` always.
    """
    lon_min, lon_max = float(lon_min), float(lon_max)
    if lon_max < lon_min:
        lon_max += 360.0
    return lon_min, lon_max


def unit_vector(lon_deg: np.ndarray | float, lat_deg: np.ndarray | float) -> np.ndarray:
    """Unit radius vector of planetocentric (lon, lat).

    Parameters
    ----------
    lon_deg, lat_deg : float arrays (broadcastable), degrees
        East-positive longitude, planetocentric latitude.

    Returns
    -------
    (..., 3) float64
        (cos φ cos λ, cos φ sin λ, sin φ) in the body-fixed frame.
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon, lat = np.broadcast_arrays(lon, lat)
    cos_lat = np.cos(lat)
    return np.stack([cos_lat * np.cos(lon), cos_lat * np.sin(lon), np.sin(lat)], axis=-1)


def local_radius(unit: np.ndarray, radii: float | tuple[float, float, float]) -> np.ndarray:
    """Radius of the reference surface along unit vectors.

    Parameters
    ----------
    unit : (..., 3) float
        Unit vectors from the body's centre.
    radii : float or (a, b, c)
        Sphere radius, or the triaxial ellipsoid's radii, metres.

    Returns
    -------
    (...) float64, metres
    """
    u = np.asarray(unit, dtype=np.float64)
    if isinstance(radii, GeodeticEllipsoid):  # the ellipsoid's radius, not a normal height
        radii = (radii.a, radii.a, radii.c)
    if np.ndim(radii) == 0:
        return np.full(u.shape[:-1], float(radii))
    a, b, c = (float(r) for r in radii)  # type: ignore[union-attr]
    return 1.0 / np.sqrt((u[..., 0] / a) ** 2 + (u[..., 1] / b) ** 2 + (u[..., 2] / c) ** 2)


def lonlat_height_to_xyz(lon_deg: np.ndarray | float, lat_deg: np.ndarray | float,
                         height: np.ndarray | float = 0.0, *,
                         radii: float | tuple[float, float, float]) -> np.ndarray:
    """Body-fixed XYZ of planetocentric longitude, latitude and radial height.

    Parameters
    ----------
    lon_deg, lat_deg : float arrays, degrees
        East-positive longitude, planetocentric latitude (broadcastable).
    height : float array, metres
        Radial height above the reference surface (broadcastable).
    radii : float, (a, b, c) or GeodeticEllipsoid
        Reference sphere radius (demtool's maps: ``body.surface``) or ellipsoid radii,
        metres; a :class:`GeodeticEllipsoid` makes the latitude geodetic and the height
        normal to it.

    Returns
    -------
    (..., 3) float64
        Body-fixed X, Y, Z, metres.
    """
    if isinstance(radii, GeodeticEllipsoid):
        return geodetic_to_xyz(lon_deg, lat_deg, height, radii)
    unit = unit_vector(lon_deg, lat_deg)
    h = np.asarray(height, dtype=np.float64)
    distance = local_radius(unit, radii) + h
    return unit * np.asarray(distance)[..., np.newaxis]


def xyz_to_lonlat_height(xyz: np.ndarray, *, radii: float | tuple[float, float, float]
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planetocentric longitude, latitude and radial height of body-fixed points.

    Parameters
    ----------
    xyz : (..., 3) float
        Body-fixed points, metres.
    radii : float, (a, b, c) or GeodeticEllipsoid
        Reference sphere radius or ellipsoid radii, metres (a
        :class:`GeodeticEllipsoid`: geodetic latitude and normal height).

    Returns
    -------
    lon_deg : (...) float64
        East-positive longitude in (−180, 180], degrees.
    lat_deg : (...) float64
        Planetocentric latitude, degrees.
    height : (...) float64
        Radial height above the reference surface, metres.
    """
    p = np.asarray(xyz, dtype=np.float64)
    if p.shape[-1] != 3:
        raise ValueError(f"xyz must have a last axis of 3, got shape {p.shape}")
    if isinstance(radii, GeodeticEllipsoid):
        return xyz_to_geodetic(p, radii)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    horizontal = np.hypot(x, y)
    distance = np.hypot(horizontal, z)
    lon = np.degrees(np.arctan2(y, x))
    lat = np.degrees(np.arctan2(z, horizontal))
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = p / distance[..., np.newaxis]
    height = distance - local_radius(unit, radii)
    return lon, lat, height


def enu_frame(lon_deg: np.ndarray | float, lat_deg: np.ndarray | float) -> np.ndarray:
    """Local east-north-up frames at planetocentric (lon, lat).

    "Up" is the radius vector (the reference sphere's normal), east is along the
    parallel, north along the meridian toward +Z.

    Parameters
    ----------
    lon_deg, lat_deg : float arrays, degrees (broadcastable)

    Returns
    -------
    (..., 3, 3) float64
        Rows are the east, north and up unit vectors in the body-fixed frame, so
        ``frame @ v`` gives a body-fixed vector's (e, n, u) components and
        ``frame.swapaxes(-1, -2) @ enu`` turns local components back to body-fixed.
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon, lat = np.broadcast_arrays(lon, lat)
    sl, cl = np.sin(lon), np.cos(lon)
    sp, cp = np.sin(lat), np.cos(lat)
    zero = np.zeros_like(lon)
    east = np.stack([-sl, cl, zero], axis=-1)
    north = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    up = np.stack([cp * cl, cp * sl, sp], axis=-1)
    return np.stack([east, north, up], axis=-2)
