"""Output CRSs chosen by the user (``--t-srs``) and grids turned along a stereo pair's
parallax.

``--t-srs`` (``dem``, ``mapproject``, ``fuse``) takes any CRS PROJ knows, as ASP's
``point2dem --t_srs`` and GDAL's ``-t_srs`` do: an authority code (``EPSG:32740`` for
UTM 40 S, ``IAU_2015:30110`` for the Moon's equirectangular map), a PROJ string
(``+proj=stere +lat_0=-90 +R=1737400``) or WKT.  It must be a projected CRS (the grids'
spacing is in metres) of the body the images see; its own surface (sphere or
ellipsoid) is the reference of the heights written (:func:`~demtool.maps.projections.
crs_surface`).

:func:`parallax_aligned_crs` builds a Hotine oblique Mercator (EPSG method 9815,
PROJ ``omerc``) centred on a footprint whose grid x axis runs along a given azimuth:
map-projected stereo then finds the pair's parallax along map x, where ``sgm``
searches, whatever the pair's flight direction (an along-track Pléiades pair's parallax
runs north–south).
"""

from __future__ import annotations

from typing import Any

from demtool.maps.bodies import Body, body_from_crs, same_body, to_pyproj_crs

__all__ = ["parallax_aligned_crs", "parse_t_srs"]


def parse_t_srs(text: str, body: Body | None = None, *, option: str = "--t-srs"):
    """The projected CRS a ``--t-srs`` names, checked against the images' body.

    Parameters
    ----------
    text : str
        Authority code, PROJ string or WKT.
    body : Body, optional
        The body the data are on; a CRS of another body is refused.
    option : str
        The option's name, for the messages.

    Returns
    -------
    pyproj.CRS

    Raises
    ------
    ValueError
        One line: PROJ does not know it, it is not projected (metres), or it is on
        another body.
    """
    from pyproj.exceptions import CRSError

    try:
        crs = to_pyproj_crs(text)
    except CRSError as exc:
        reason = str(exc).split(": ")[-1].strip() or "unknown"
        raise ValueError(f"{option} {text}: PROJ does not know this CRS ({reason})") from None
    if not crs.is_projected:
        raise ValueError(f"{option} {text}: {crs.name!r} is not a projected CRS; the map's "
                         "pixel size is in metres (give e.g. a UTM zone, EPSG:32740, or an "
                         "IAU_2015 projected code)")
    if body is not None:
        crs_body = body_from_crs(crs)
        if not same_body(crs_body, body):
            raise ValueError(f"{option} {text}: is a CRS of {crs_body.name} but the data are "
                             f"of {body.name}")
    return crs


def parallax_aligned_crs(body: Body, center_lon: float, center_lat: float,
                         azimuth_deg: float) -> Any:
    """A projected CRS on ``body``'s map surface whose x axis runs along ``azimuth_deg``
    (degrees clockwise from north) through the centre (lon, lat), scale 1 there.

    Hotine oblique Mercator, variant B (``omerc``): its initial line has the azimuth
    (folded into −90…90°: a line has no direction) and the grid is turned 90° from it
    (``gamma = 90``), so grid x follows the line.

    Returns
    -------
    pyproj.CRS
    """
    from pyproj.crs import ProjectedCRS
    from pyproj.crs.coordinate_operation import HotineObliqueMercatorBConversion

    azimuth = (float(azimuth_deg) + 90.0) % 180.0 - 90.0
    conversion = HotineObliqueMercatorBConversion(
        latitude_projection_centre=float(center_lat),
        longitude_projection_centre=float(center_lon), azimuth_projection_centre=azimuth,
        angle_from_rectified_to_skew_grid=90.0, scale_factor_projection_centre=1.0,
        easting_projection_centre=0.0, northing_projection_centre=0.0)
    base = body.geographic_crs()
    label = base.name.split(" / ")[0]
    return ProjectedCRS(conversion=conversion, geodetic_crs=base,
                        name=f"{label} / Oblique Mercator along {azimuth:.4g}°, centre "
                             f"{center_lon:.6g} {center_lat:.6g}")
