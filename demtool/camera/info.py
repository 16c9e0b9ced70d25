"""What a camera model sees: footprint, GSD, viewing and sun angles, pair geometry.

The core of ``demtool camera`` (ISIS ``caminfo``/``campt``, ASP ``camera_footprint``):
pure functions of :class:`~demtool.sensors.base.SensorModel` objects, vectorised over
the points they sample.

Two surfaces are handled:

* a **body** (:class:`~demtool.maps.Body`): rays meet the body's reference sphere
  (:attr:`Body.radius`), the surface ``synth``, ``mapproject`` and ``dem`` put heights on
  (issue 46: on Mars the ellipsoid lies up to 20 km below the sphere, and two CTX windows
  of one point "did not overlap" on it; an RPC's ground is at its height offset above
  WGS 84, its centre latitude geodetic, as ``mapproject`` and ``dem`` have them);
  positions are reported as planetocentric,
  east-positive longitude / latitude (degrees); "up" is the radius vector (the local
  east-north-up frame of :func:`demtool.maps.enu_frame`); altitudes are above the
  body's reference sphere (:attr:`Body.radius`); areas are on that sphere, computed in a
  Lambert azimuthal equal-area projection centred on the footprint (exact areas for
  the polygon's vertices; the polygon's edges are straight in that projection).
* the **local world frame** of demtool's synthetic scenes and ``cameras.npz``
  (``body=None``): the plane Z = 0, up = +Z, positions and areas in metres.

Pixel convention: CSM's, the centre of the first pixel at (line, sample) = (0.5, 0.5);
the image covers ``0 ≤ line ≤ lines``, ``0 ≤ sample ≤ samples`` and its centre is at
``(lines / 2, samples / 2)``.

Angles at a ground point G with up vector n, sensor position C and sun position S
(ISIS ``Camera::IncidenceAngle``/``EmissionAngle``/``PhaseAngle`` on the sphere's
normal): incidence = ∠(n, S − G), emission = ∠(n, C − G), phase = ∠(S − G, C − G);
sun azimuth clockwise from north and elevation = 90° − incidence in the ENU frame.

Pair geometry at the centre G of the two footprints' intersection (ASP ``stereo_parse``
reports the same convergence angle): convergence = ∠(C₁ − G, C₂ − G), base
B = |C₁ − C₂|, height H = ((C₁ + C₂)/2 − G) · n, base-to-height ratio B/H.  For a line
scanner, C is the sensor position at the time the sensor images G.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from demtool.maps import Body, enu_frame, unit_vector, xyz_to_lonlat_height
from demtool.sensors.base import SensorModel, ray_ellipsoid_intersection
from demtool.sensors.polygons import (
    laea_forward,
    laea_inverse,
    polygon_area,
    polygon_intersection,
)

__all__ = ["Footprint", "camera_info", "center_geometry", "footprint", "image_boundary",
           "pair_geometry", "surface_points"]

#: a sun closer than this to the body's centre (metres) means "the model has no sun"
_NO_SUN = 1.0
_BISECTIONS = 40


def image_boundary(lines: int, samples: int, points_per_edge: int = 32
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Points along the image's outer edges, corners included, once around.

    Parameters
    ----------
    lines, samples : int
        Image size in pixels.
    points_per_edge : int
        Points on each edge, counting its first corner (≥ 1).

    Returns
    -------
    line, sample : (4 * points_per_edge,) float64
        CSM image coordinates, from (0, 0) along the first line to (0, samples), down to
        (lines, samples), back to (lines, 0) and up towards (0, 0).
    """
    t = np.arange(points_per_edge) / points_per_edge
    line = np.concatenate([np.zeros_like(t), t * lines, np.full_like(t, lines),
                           (1.0 - t) * lines])
    sample = np.concatenate([t * samples, np.full_like(t, samples), (1.0 - t) * samples,
                             np.zeros_like(t)])
    return line, sample


def surface_points(model: SensorModel, line, sample, body: Body | None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Ground points of image points on the surface, and which rays hit it.

    Parameters
    ----------
    model : SensorModel
    line, sample : array_like, shape S
        CSM image coordinates.
    body : Body or None
        ``None``: the plane Z = 0 of the local world frame; otherwise the body's
        reference sphere (``body.radius``).

    Returns
    -------
    xyz : S + (3,) float64, metres
        NaN where the ray misses.
    hit : S bool
    """
    ray = model.image_to_ray(line, sample)
    if body is None:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -ray.origin[..., 2] / ray.direction[..., 2]
        hit = np.isfinite(s) & (s > 0)
        xyz = ray.origin + np.where(hit, s, np.nan)[..., None] * ray.direction
        return xyz, hit
    if hasattr(model, "domain"):  # an RPC: its ground at its height offset (the terrain it
        # was fitted around), where mapproject and dem put it too (heights above WGS 84)
        with np.errstate(invalid="ignore"):
            xyz = np.asarray(model.image_to_ground(line, sample, model.rpc["height_off"]))
        hit = np.isfinite(xyz).all(axis=-1)
        return np.where(hit[..., None], xyz, np.nan), hit
    radius = float(body.radius)
    xyz, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, radius, radius,
                                          return_hit=True)
    return np.where(hit[..., None], xyz, np.nan), hit


def _up(xyz: np.ndarray, body: Body | None) -> np.ndarray:
    if body is None:
        return np.broadcast_to([0.0, 0.0, 1.0], np.shape(xyz)).copy()
    return xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)


class Footprint(NamedTuple):
    """An image's footprint polygon on the surface.

    xyz : (N, 3) float64, metres, the boundary once around (NaN-free).
    line, sample : (N,) float64, the image points they come from (limb points included).
    x, y : (N,) float64, metres, on the local plane: the Lambert azimuthal equal-area
        projection centred at ``center_lonlat`` on the body's sphere, or the world X, Y.
    area_m2 : float, on the reference sphere (or the plane).
    missed : int, boundary points whose ray misses the surface (replaced by limb points).
    center_lonlat : (float, float) or None, degrees, the projection's centre.
    """

    xyz: np.ndarray
    line: np.ndarray
    sample: np.ndarray
    x: np.ndarray
    y: np.ndarray
    area_m2: float
    missed: int
    center_lonlat: tuple[float, float] | None


def _limb(model: SensorModel, line, sample, body: Body | None, centre: tuple[float, float]):
    """Last image points on the segments from the image centre (which hits) towards
    ``(line, sample)`` (which miss) whose rays still hit: bisection, vectorised."""
    lc, sc = centre
    lo = np.zeros(np.shape(line))
    hi = np.ones(np.shape(line))
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        _, hit = surface_points(model, lc + mid * (line - lc), sc + mid * (sample - sc), body)
        lo = np.where(hit, mid, lo)
        hi = np.where(hit, hi, mid)
    return lc + lo * (line - lc), sc + lo * (sample - sc)


def footprint(model: SensorModel, body: Body | None, *, points_per_edge: int = 32,
              center_lonlat: tuple[float, float] | None = None) -> Footprint | None:
    """The image's footprint: its boundary (:func:`image_boundary`) on the surface.

    A model with lines outside its sampled ephemeris (:mod:`demtool.sensors.coverage`)
    is outlined on its largest run of covered lines.

    Boundary points whose rays miss the body are moved along the segment towards the
    image centre to the limb (bisection to 2⁻⁴⁰ of the segment), so an image seeing
    the limb gets the limb as part of its outline.

    Parameters
    ----------
    model : SensorModel
    body : Body or None
        See :func:`surface_points`.
    points_per_edge : int
        Boundary samples per image edge.
    center_lonlat : (float, float), optional
        Centre of the equal-area projection (default: the ground point of the image
        centre, or the mean direction of the outline when that misses).

    Returns
    -------
    Footprint or None
        None when no boundary point and not the image centre sees the surface.
    """
    from demtool.sensors.coverage import covered_lines

    # Lines exposed outside the sampled ephemeris are masked: outline the largest run
    # of covered lines instead (demtool.sensors.coverage).
    first, last = max(covered_lines(model) or [(0, -1)], key=lambda run: run[1] - run[0])
    partial = (first, last) != (0, model.lines - 1)
    line, sample = image_boundary(last + 1 - first - (1e-6 if partial else 0.0),
                                  model.samples, points_per_edge)
    line = line + first
    xyz, hit = surface_points(model, line, sample, body)
    centre = (0.5 * (first + last + 1), 0.5 * model.samples)
    _, centre_hit = surface_points(model, *centre, body)
    missed = int((~hit).sum())
    if missed and bool(centre_hit):
        line, sample = line.copy(), sample.copy()
        line[~hit], sample[~hit] = _limb(model, line[~hit], sample[~hit], body, centre)
        xyz, hit = surface_points(model, line, sample, body)
    line, sample, xyz = line[hit], sample[hit], xyz[hit]
    if len(xyz) < 3:
        return None
    if body is None:
        x, y = xyz[:, 0], xyz[:, 1]
    else:
        if center_lonlat is None:
            mean = xyz.mean(axis=0) if not bool(centre_hit) else \
                surface_points(model, *centre, body)[0]
            lon, lat, _ = xyz_to_lonlat_height(mean, radii=1.0)
            center_lonlat = (float(lon), float(lat))
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=1.0)
        x, y = laea_forward(lon, lat, *center_lonlat, body.radius)
    area = polygon_area(x, y)
    if area < 0:  # keep the outline counter-clockwise on the map
        xyz, line, sample, x, y = (v[::-1] for v in (xyz, line, sample, x, y))
    return Footprint(xyz, line, sample, x, y, abs(area), missed, center_lonlat)


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between vectors (..., 3), degrees (atan2 form: accurate near 0 and 180°)."""
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(u * v, axis=-1)))


def _lonlat(xyz: np.ndarray) -> tuple[float, float]:
    lon, lat, _ = xyz_to_lonlat_height(np.asarray(xyz, dtype=np.float64), radii=1.0)
    return float(lon), float(lat)


def center_geometry(model: SensorModel, body: Body | None) -> dict[str, Any]:
    """Ground point, GSD, altitude and angles at the image centre.

    Returns
    -------
    dict
        ``center_line``, ``center_sample``; ``center_xyz_m`` (None when the centre misses
        the surface); on a body ``center_lon_deg``, ``center_lat_deg``; ``gsd_line_m``,
        ``gsd_sample_m`` (ground distance between the points half a pixel either side of
        the centre, along the line and sample directions), ``gsd_m`` (their mean);
        ``spacecraft_xyz_m``, ``altitude_m`` (above the reference sphere, or above
        Z = 0), ``slant_range_m``; ``emission_deg``, and when the model has a sun
        ``incidence_deg``, ``phase_deg``, ``sun_azimuth_deg``, ``sun_elevation_deg``,
        ``subsolar_lon_deg``/``subsolar_lat_deg`` (a body); ``notes`` (list of str).
    """
    lc, sc = 0.5 * model.lines, 0.5 * model.samples
    out: dict[str, Any] = {"center_line": lc, "center_sample": sc, "notes": []}
    notes = out["notes"]
    ground, hit = surface_points(model, lc, sc, body)
    position = np.asarray(model.camera_center(np.float64(lc)), dtype=np.float64)
    out["spacecraft_xyz_m"] = position.tolist()
    if body is None:
        out["altitude_m"] = float(position[2])
    else:
        out["altitude_m"] = float(np.linalg.norm(position) - body.radius)
        out["spacecraft_lon_deg"], out["spacecraft_lat_deg"] = _lonlat(position)
    if not bool(hit):
        notes.append("the image centre misses the surface: no ground point, GSD or angles")
        out["center_xyz_m"] = None
        return out
    out["center_xyz_m"] = ground.tolist()
    if body is not None:
        out["center_lon_deg"], out["center_lat_deg"] = _lonlat(ground)
        if body.height_reference == "ellipsoid":  # geodetic, as the map and the model
            lon, lat, _ = xyz_to_lonlat_height(ground, radii=body.surface)
            out["center_lon_deg"], out["center_lat_deg"] = float(lon), float(lat)
        out["center_radius_m"] = float(np.linalg.norm(ground))
    half = np.array([-0.5, 0.5])
    along_line, _ = surface_points(model, lc + half, np.full(2, sc), body)
    along_sample, _ = surface_points(model, np.full(2, lc), sc + half, body)
    out["gsd_line_m"] = float(np.linalg.norm(along_line[1] - along_line[0]))
    out["gsd_sample_m"] = float(np.linalg.norm(along_sample[1] - along_sample[0]))
    out["gsd_m"] = 0.5 * (out["gsd_line_m"] + out["gsd_sample_m"])
    up = _up(ground, body)
    view = position - ground
    out["slant_range_m"] = float(np.linalg.norm(view))
    out["emission_deg"] = float(_angle(up, view))
    try:
        sun = np.asarray(model.sun_position(np.float64(lc)), dtype=np.float64)
    except ValueError:
        sun = None
    if sun is None or not np.all(np.isfinite(sun)) or np.linalg.norm(sun) < _NO_SUN:
        notes.append("the model carries no sun position: incidence, phase and sun angles "
                     "omitted")
        return out
    to_sun = sun - ground
    out["incidence_deg"] = float(_angle(up, to_sun))
    out["phase_deg"] = float(_angle(to_sun, view))
    if body is None:
        east, north = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    else:
        east, north, _ = enu_frame(out["center_lon_deg"], out["center_lat_deg"])
        out["subsolar_lon_deg"], out["subsolar_lat_deg"] = _lonlat(sun)
    # rounded to 1e-9° before the modulo: a sun due north is 0°, not 359.9999999999
    out["sun_azimuth_deg"] = float(round(float(np.degrees(np.arctan2(to_sun @ east,
                                                                     to_sun @ north))), 9)
                                   % 360.0)
    out["sun_elevation_deg"] = 90.0 - out["incidence_deg"]
    return out


def _sensor_position_seeing(model: SensorModel, ground: np.ndarray) -> np.ndarray:
    """Sensor position when it images ``ground`` (line scanners: at that line's time)."""
    line, _ = model.ground_to_image(ground)
    line = np.float64(line)
    if not np.isfinite(line):
        line = np.float64(0.5 * model.lines)
    return np.asarray(model.camera_center(line), dtype=np.float64)


def pair_geometry(first: SensorModel, second: SensorModel, body: Body | None, *,
                  points_per_edge: int = 32) -> dict[str, Any]:
    """Convergence, base-to-height ratio and footprint overlap of two models.

    The footprints are projected on one equal-area plane (centred between the two
    image centres' ground points) and intersected exactly
    (:func:`demtool.sensors.polygons.polygon_intersection`); the pair geometry is
    measured at the intersection's centroid G, on the surface (see the module
    docstring).

    Returns
    -------
    dict
        ``overlap_area_km2``, ``overlap_fraction_first``, ``overlap_fraction_second``
        (intersection area over each footprint's area), ``overlap_center_lon_deg``/
        ``_lat_deg`` (a body) or ``overlap_center_xyz_m``, ``convergence_deg``,
        ``base_m``, ``height_m``, ``base_to_height``; ``notes``.  The angles are None
        when the footprints do not overlap.
    """
    out: dict[str, Any] = {"notes": []}
    centers = [surface_points(m, 0.5 * m.lines, 0.5 * m.samples, body) for m in
               (first, second)]
    seen = [xyz for xyz, hit in centers if bool(hit)]
    center_lonlat = None
    if body is not None and seen:
        center_lonlat = _lonlat(np.mean([x / np.linalg.norm(x) for x in seen], axis=0))
    prints = [footprint(m, body, points_per_edge=points_per_edge, center_lonlat=center_lonlat)
              for m in (first, second)]
    if body is not None and center_lonlat is None and all(p is not None for p in prints):
        # neither image centre sees the body: one plane centred on both outlines
        outline = np.concatenate([p.xyz for p in prints])
        center_lonlat = _lonlat((outline / np.linalg.norm(outline, axis=1)[:, None]).mean(0))
        prints = [footprint(m, body, points_per_edge=points_per_edge,
                            center_lonlat=center_lonlat) for m in (first, second)]
    keys = ("overlap_area_km2", "overlap_fraction_first", "overlap_fraction_second",
            "convergence_deg", "base_m", "height_m", "base_to_height")
    out.update(dict.fromkeys(keys))
    if prints[0] is None or prints[1] is None:
        out["notes"].append("a footprint misses the surface: no overlap")
        return out
    a, b = prints
    area, (cx, cy) = polygon_intersection(a.x, a.y, b.x, b.y)
    out["overlap_area_km2"] = area / 1e6
    out["overlap_fraction_first"] = area / a.area_m2
    out["overlap_fraction_second"] = area / b.area_m2
    if area <= 0:
        out["notes"].append("the footprints do not overlap")
        return out
    if body is None:
        ground = np.array([cx, cy, 0.0])
        out["overlap_center_xyz_m"] = ground.tolist()
    else:
        lon, lat = laea_inverse(np.float64(cx), np.float64(cy), *center_lonlat, body.radius)
        out["overlap_center_lon_deg"], out["overlap_center_lat_deg"] = float(lon), float(lat)
        # the surface point in that direction, on the body's reference sphere
        ground = float(body.radius) * unit_vector(lon, lat)
    c1 = _sensor_position_seeing(first, ground)
    c2 = _sensor_position_seeing(second, ground)
    up = _up(ground, body)
    out["convergence_deg"] = float(_angle(c1 - ground, c2 - ground))
    out["base_m"] = float(np.linalg.norm(c1 - c2))
    out["height_m"] = float((0.5 * (c1 + c2) - ground) @ up)
    out["base_to_height"] = out["base_m"] / out["height_m"] if out["height_m"] > 0 else None
    return out


def _same_surface(first: SensorModel, second: SensorModel) -> bool:
    if first.radii is None or second.radii is None:
        return first.radii is None and second.radii is None
    return bool(np.allclose(first.radii, second.radii, rtol=1e-6))


def camera_info(models: Mapping[str, SensorModel], bodies: Mapping[str, Body | None], *,
                points_per_edge: int = 32) -> dict[str, Any]:
    """Everything ``demtool camera`` reports, for each model and each pair.

    Parameters
    ----------
    models : mapping name → SensorModel
    bodies : mapping name → Body or None
        Each model's body (None: the local world frame, see the module docstring).
    points_per_edge : int
        Footprint samples per image edge.

    Returns
    -------
    dict
        ``cameras``: one dict per model (``name``, ``kind``, ``lines``, ``samples``,
        ``body``…, the keys of :func:`center_geometry` and ``footprint``: ``points``,
        ``missed_points``, ``area_km2`` and ``lon_deg``/``lat_deg`` or ``x_m``/``y_m``);
        ``pairs``: one dict per pair of models on the same surface (``first``,
        ``second`` and the keys of :func:`pair_geometry`).
    """
    cameras = []
    for name, model in models.items():
        body = bodies[name]
        entry: dict[str, Any] = {"name": name, "kind": model.kind or type(model).__name__,
                                 "lines": int(model.lines), "samples": int(model.samples)}
        if body is None:
            entry.update(frame="local", body=None)
        else:
            entry.update(frame="body", body=body.name, body_naif_id=body.naif_id,
                         radii_m=list(body.radii), reference_radius_m=body.radius)
        entry.update(center_geometry(model, body))
        entry["notes"] = list(getattr(model, "notes", [])) + entry["notes"]
        if getattr(model, "coverage", None) is not None:
            from demtool.sensors.coverage import covered_lines

            # [first, end) rows whose exposure the position and pointing samples cover
            entry["covered_lines"] = [[a, b + 1] for a, b in covered_lines(model)]
        fp = footprint(model, body, points_per_edge=points_per_edge)
        if fp is None:
            entry["footprint"] = None
            entry["notes"].append("the image does not see the surface: no footprint")
        else:
            polygon: dict[str, Any] = {"points": len(fp.xyz), "missed_points": fp.missed,
                                       "area_km2": fp.area_m2 / 1e6}
            if body is None:
                polygon.update(x_m=fp.xyz[:, 0].tolist(), y_m=fp.xyz[:, 1].tolist())
            else:
                lon, lat, _ = xyz_to_lonlat_height(fp.xyz, radii=1.0)
                polygon.update(lon_deg=lon.tolist(), lat_deg=lat.tolist())
            entry["footprint"] = polygon
            if fp.missed:
                entry["notes"].append(f"{fp.missed} of {4 * points_per_edge} footprint "
                                      "points miss the body: the outline follows the limb")
        cameras.append(entry)
    names = list(models)
    pairs = []
    for i, first in enumerate(names):
        for second in names[i + 1:]:
            pair: dict[str, Any] = {"first": first, "second": second}
            if not _same_surface(models[first], models[second]):
                pair["notes"] = ["the models are on different bodies or frames: no pair "
                                 "geometry"]
            else:
                pair.update(pair_geometry(models[first], models[second], bodies[first],
                                          points_per_edge=points_per_edge))
            pairs.append(pair)
    return {"cameras": cameras, "pairs": pairs}
