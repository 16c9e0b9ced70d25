"""``camera --footprints FILE.geojson``: footprints and overlaps as GeoJSON polygons.

ISIS (``footprintinit``) and ASP (``camera_footprint``) users put image footprints on a
map in QGIS; this writes them as an RFC 7946 GeoJSON FeatureCollection:

* one Feature per image on a body (``"role": "footprint"``): the footprint outline of
  :func:`demtool.camera.info.footprint` (``--points-per-edge`` samples per image edge)
  as longitude/latitude in degrees (planetocentric, east-positive, on the body), with
  the image's GSD, emission/incidence/phase angles, sun azimuth and elevation, area
  and ephemeris time (TDB seconds past J2000, from the model) as properties;
* one Feature per overlapping pair (``"role": "overlap"``): the intersection of the two
  footprints, computed on the Lambert azimuthal equal-area plane centred on the pair
  (as :func:`demtool.camera.info.pair_geometry` measures its area; shapely/GEOS for the
  polygon), with the pair's overlap area, fractions, convergence and base-to-height.

RFC 7946 §3.1.9 (antimeridian) — a polygon that crosses ±180° is cut in two along it
and written as a MultiPolygon; §3.1.6 rings are counter-clockwise.  A footprint
around a pole (its longitudes wind once around) is closed along the pole's latitude
±90° before the cut, so its lon/lat polygon covers the cap, as GeoJSON tools draw it.
Edges are straight in longitude/latitude (RFC 7946 §3.1.1); the footprint is densely
sampled, so they follow the outline.  GeoJSON names no body: the FeatureCollection
carries it as the foreign member ``body`` (name, NAIF id, radii), and each Feature as a
property, for tools that need it (QGIS reads the lon/lat as they are).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["footprint_collection", "lonlat_polygons", "overlap_lonlat"]

_CAMERA_PROPERTIES = ("kind", "lines", "samples", "gsd_m", "gsd_line_m", "gsd_sample_m",
                      "emission_deg", "incidence_deg", "phase_deg", "sun_azimuth_deg",
                      "sun_elevation_deg", "center_lon_deg", "center_lat_deg", "altitude_m",
                      "slant_range_m", "file")
_PAIR_PROPERTIES = ("overlap_area_km2", "overlap_fraction_first", "overlap_fraction_second",
                    "convergence_deg", "base_m", "height_m", "base_to_height")


def _unwrap(lon: np.ndarray) -> np.ndarray:
    """Longitudes made continuous along the ring (steps of at most 180°)."""
    return np.degrees(np.unwrap(np.radians(lon)))


def lonlat_polygons(lon_deg: Sequence[float], lat_deg: Sequence[float]) -> list[Any]:
    """A closed outline on the sphere as GeoJSON-ready shapely polygons in lon/lat.

    Parameters
    ----------
    lon_deg, lat_deg : (n,) float, degrees
        The outline's vertices once around (either orientation), not repeated.

    Returns
    -------
    list of shapely.Polygon
        One polygon, or the pieces cut at ±180° (RFC 7946 §3.1.9), each with longitudes
        within [-180, 180], counter-clockwise exterior.  An outline around a pole is
        closed along latitude ±90° first.
    """
    from shapely import Polygon, box, make_valid
    from shapely.geometry.polygon import orient

    lon = _unwrap(np.asarray(lon_deg, dtype=np.float64))
    lat = np.asarray(lat_deg, dtype=np.float64)
    winding = (lon[-1] + _step(lon[-1], lon[0])) - lon[0]
    if abs(winding) > 180.0:  # the ring goes once around a pole: close it at the pole
        pole = 90.0 if np.mean(lat) > 0 else -90.0
        end = lon[0] + winding
        lon = np.concatenate([lon, [end, end, lon[0]]])
        lat = np.concatenate([lat, [lat[0], pole, pole]])
    shift = 360.0 * np.floor((np.min(lon) + 180.0) / 360.0)
    lon = lon - shift  # the westernmost vertex within [-180, 180)
    ring = Polygon(np.column_stack([lon, lat]))
    if not ring.is_valid:
        ring = make_valid(ring)
    from shapely import unary_union

    pieces = []
    for offset in (0.0, 360.0):
        part = ring.intersection(box(-180.0 + offset, -90.0, 180.0 + offset, 90.0))
        for geometry in getattr(part, "geoms", [part]):
            if geometry.geom_type == "Polygon" and geometry.area > 0:
                coords = np.asarray(geometry.exterior.coords) - [offset, 0.0]
                holes = [np.asarray(h.coords) - [offset, 0.0] for h in geometry.interiors]
                pieces.append(Polygon(coords, holes))
    # a polar cap's two pieces meet along the closing meridian: one polygon again
    merged = unary_union(pieces) if pieces else None
    return [orient(g, sign=1.0) for g in getattr(merged, "geoms", [merged])
            if g is not None and g.geom_type == "Polygon" and g.area > 0]


def _step(a: float, b: float) -> float:
    """The longitude step from a to b, within (-180, 180]."""
    return (b - a + 180.0) % 360.0 - 180.0


def overlap_lonlat(first: Mapping[str, Any], second: Mapping[str, Any], radius: float
                   ) -> tuple[list[Any], float]:
    """The intersection of two footprints (lon/lat lists of ``camera``'s report).

    Both outlines go onto the Lambert azimuthal equal-area plane centred between them
    (:func:`demtool.sensors.polygons.laea_forward`), are intersected there (shapely),
    and come back to lon/lat (:func:`lonlat_polygons`).

    Returns
    -------
    polygons : list of shapely.Polygon
        Empty when they do not overlap.
    area_m2 : float
        The intersection's area on the plane (equal-area: on the sphere), m².
    """
    from shapely import Polygon, make_valid

    from demtool.maps.frames import unit_vector, xyz_to_lonlat_height
    from demtool.sensors.polygons import laea_forward, laea_inverse

    outlines = [(np.asarray(f["lon_deg"]), np.asarray(f["lat_deg"])) for f in (first, second)]
    centre = np.mean([unit_vector(lon, lat).mean(axis=0) for lon, lat in outlines], axis=0)
    lon0, lat0, _ = xyz_to_lonlat_height(centre / np.linalg.norm(centre), radii=1.0)
    lon0, lat0 = float(lon0), float(lat0)
    planes = []
    for lon, lat in outlines:
        x, y = laea_forward(lon, lat, lon0, lat0, radius)
        polygon = Polygon(np.column_stack([x, y]))
        planes.append(polygon if polygon.is_valid else make_valid(polygon))
    common = planes[0].intersection(planes[1])
    out = []
    for geometry in getattr(common, "geoms", [common]):
        if geometry.geom_type != "Polygon" or geometry.area <= 0:
            continue
        x, y = np.asarray(geometry.exterior.coords)[:-1].T
        lon, lat = laea_inverse(x, y, lon0, lat0, radius)
        out.extend(lonlat_polygons(lon, lat))
    return out, float(common.area)


def _geometry(polygons: list[Any]) -> dict[str, Any] | None:
    from shapely import MultiPolygon
    from shapely.geometry import mapping

    if not polygons:
        return None
    shape = polygons[0] if len(polygons) == 1 else MultiPolygon(polygons)
    return mapping(shape)


def _time(model: Any) -> float | None:
    for name in ("time", "center_time"):
        value = getattr(model, name, None)
        if value is not None and np.isfinite(value):
            return float(value)
    return None


def footprint_collection(report: Mapping[str, Any], models: Mapping[str, Any],
                         bodies: Mapping[str, Any]) -> dict[str, Any]:
    """The GeoJSON FeatureCollection of ``camera``'s report (see the module docstring).

    Parameters
    ----------
    report : mapping
        :func:`demtool.camera.info.camera_info`'s report (``cameras``, ``pairs``).
    models, bodies : mapping name → SensorModel, Body or None
        The models (for their times) and their bodies; models in a local frame (no
        body) have no longitude and latitude and are left out (named in
        ``left_out``, a foreign member).

    Returns
    -------
    dict
        JSON-ready GeoJSON.
    """
    features: list[dict[str, Any]] = []
    left_out: list[str] = []
    outlines = {}
    collection_body = None
    for camera in report["cameras"]:
        name, body = camera["name"], bodies.get(camera["name"])
        footprint = camera.get("footprint")
        if body is None or not footprint or "lon_deg" not in footprint:
            left_out.append(name)
            continue
        outlines[name] = footprint
        collection_body = collection_body or {"name": body.name, "naif_id": body.naif_id,
                                              "radii_m": list(body.radii)}
        properties = {"role": "footprint", "name": name, "body": body.name,
                      **{k: camera.get(k) for k in _CAMERA_PROPERTIES if k in camera},
                      "area_km2": footprint["area_km2"],
                      "ephemeris_time_tdb_s": _time(models[name]),
                      "missed_points": footprint["missed_points"]}
        features.append({"type": "Feature", "properties": properties,
                         "geometry": _geometry(lonlat_polygons(footprint["lon_deg"],
                                                               footprint["lat_deg"]))})
    for pair in report["pairs"]:
        first, second = pair["first"], pair["second"]
        if first not in outlines or second not in outlines or not pair.get("overlap_area_km2"):
            continue
        polygons, area = overlap_lonlat(outlines[first], outlines[second],
                                        bodies[first].radius)
        if not polygons:
            continue
        properties = {"role": "overlap", "name": f"{first} ∩ {second}", "first": first,
                      "second": second, "body": bodies[first].name,
                      **{k: pair.get(k) for k in _PAIR_PROPERTIES},
                      "polygon_area_km2": area / 1e6}
        features.append({"type": "Feature", "properties": properties,
                         "geometry": _geometry(polygons)})
    collection: dict[str, Any] = {"type": "FeatureCollection", "features": features}
    if collection_body is not None:
        collection["body"] = collection_body
    if left_out:
        collection["left_out"] = left_out
    return collection
