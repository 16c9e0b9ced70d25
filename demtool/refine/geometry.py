"""Sun and view directions on the body's map, for shape from shading of map-projected images.

On a map grid the SfS "grid frame" (x = columns, y = up the rows, z = up; CONTRIBUTING.md)
is, at each point, the local east-north-up frame of the body (:func:`demtool.maps.enu_frame`)
turned so that x follows the map's +x and y the map's +y (a north-up equirectangular map:
x east, y north; a polar stereographic one: the grid axes are turned from east/north by the
longitude).  The sun and the sensor are body-fixed positions (the sensor model's
``sun_position`` and ``camera_center`` at the exposure of the image line that sees the
point); their directions from the ground point, expressed in that frame, are the sun and
view vectors SfS needs.  Heights are above the reference sphere, measured radially, so each
point's "up" is its radius vector.

Large images see the sun and the sensor from directions that change across the map (a
line scanner's view changes across its swath; the local vertical turns by d/R over a
distance d): :func:`illumination_grid` samples the directions on a coarse lattice and
:func:`angular_spread` says how much they vary, so the runner can refine per tile.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

__all__ = ["MapIllumination", "angular_spread", "grid_frames", "illumination_grid"]


def grid_frames(crs: Any, x: np.ndarray, y: np.ndarray, heights: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Ground points and local grid frames at map points.

    Parameters
    ----------
    crs : CRS-like, projected, on the body's sphere
    x, y : S float, map units
    heights : S float, metres above the sphere

    Returns
    -------
    xyz : S + (3,) float64, body-fixed metres
    frame : S + (3, 3) float64
        Rows: unit vectors (body-fixed) of the grid's x (map +x in the tangent plane),
        y (map +y, orthogonalised) and z (the radius vector, up).
    """
    from demtool.maps import map_to_xyz

    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    h = np.broadcast_to(np.asarray(heights, dtype=np.float64), x.shape)
    xyz = map_to_xyz(crs, x, y, h)
    step = 1.0  # map units (metres): central differences of the projection
    dx = map_to_xyz(crs, x + step, y, h) - map_to_xyz(crs, x - step, y, h)
    up = xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)
    ex = dx - np.sum(dx * up, axis=-1, keepdims=True) * up
    ex /= np.linalg.norm(ex, axis=-1, keepdims=True)
    ey = np.cross(up, ex)  # conformal, north-up maps: map +y (up × east = north)
    return xyz, np.stack([ex, ey, up], axis=-2)


class MapIllumination(NamedTuple):
    """Sun and view unit vectors (grid frame) on a lattice of map points.

    sun, view : S + (3,) float64; seen : S bool (the sensor sees the point).
    """

    sun: np.ndarray
    view: np.ndarray
    seen: np.ndarray


def illumination_grid(sensor: Any, crs: Any, x: np.ndarray, y: np.ndarray,
                      heights: np.ndarray) -> MapIllumination:
    """Sun and view directions in the local grid frames of map points.

    Parameters
    ----------
    sensor : SensorModel
        Gives ``ground_to_image``, ``sun_position(line)`` and ``camera_center(line)``
        (body-fixed metres).
    crs : CRS-like, projected, on the body's sphere
    x, y : S float, map units
    heights : S float, metres above the sphere (NaN: the point is skipped)

    Returns
    -------
    MapIllumination
        Vectors NaN where the point has no height or the sensor does not see it.
    """
    x = np.asarray(x, dtype=np.float64)
    heights = np.broadcast_to(np.asarray(heights, dtype=np.float64), x.shape)
    ok = np.isfinite(heights)
    filled = np.where(ok, heights, 0.0)
    xyz, frame = grid_frames(crs, x, y, filled)
    line, sample = sensor.ground_to_image(xyz)
    seen = ok & np.isfinite(line) & np.isfinite(sample)
    safe = np.where(seen, line, 0.5 * sensor.lines)
    out = []
    for position in (sensor.sun_position(safe), sensor.camera_center(safe)):
        d = position - xyz
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        local = np.einsum("...ij,...j->...i", frame, d)
        local[~seen] = np.nan
        out.append(local)
    return MapIllumination(out[0], out[1], seen)


def angular_spread(vectors: np.ndarray) -> float:
    """Largest angle (degrees) between any of the unit vectors and their mean direction.

    vectors : (..., 3), NaN rows ignored.  0 when fewer than two are finite.
    """
    v = np.asarray(vectors, dtype=np.float64).reshape(-1, 3)
    v = v[np.isfinite(v).all(axis=1)]
    if len(v) < 2:
        return 0.0
    mean = v.mean(axis=0)
    mean /= np.linalg.norm(mean)
    return float(np.degrees(np.arccos(np.clip(v @ mean, -1.0, 1.0))).max())
