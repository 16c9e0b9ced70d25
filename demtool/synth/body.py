"""The synthetic scene placed on a spherical body.

The scene's local frame (CONTRIBUTING.md: X east, Y north, Z up, metres, origin at
the scene centre, Z = 0 the mean surface) is the local east-north-up frame
(:func:`demtool.maps.enu_frame`) of the body's reference sphere at the planetocentric
centre (λ0, φ0), with its origin on the sphere:

    X_body = O + Eᵀ x_local,       O = R · up(λ0, φ0),

E the 3 × 3 matrix whose rows are the east, north and up unit vectors.  The terrain
stays what the renderer casts rays against: the height field ``z = h(x, y)`` above
the *tangent plane* Z = 0.  Seen from the body that plane falls below the sphere's
curve only by the sagitta ``d²/(2R)`` (1.9 cm at 256 m on the Moon), but truth heights
above the sphere must carry it exactly: :func:`surface_height` finds where the radial
line through (λ, φ) meets the height field by fixed-point iteration, which converges
to round-off in a few steps because the radial line is nearly vertical in the local
frame (its slope is |x|/R, about 1e-4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from demtool.maps import Body, body_by_name, enu_frame, unit_vector

SURFACE_ITERATIONS = 8  # fixed-point steps of surface_height (3 reach 1e-12 m here)
SUN_DISTANCE_M = 1.495978707e11  # 1 au: the sun of a synthetic ISD sits this far away


@dataclass(frozen=True)
class Placement:
    """A local scene frame on a body (see the module docstring).

    Attributes
    ----------
    body : Body
        The body; its reference sphere (``body.radius``) carries the scene.
    center_lon, center_lat : float
        Planetocentric, east-positive longitude and latitude of the scene centre,
        degrees.
    """

    body: Body
    center_lon: float
    center_lat: float

    @property
    def radius(self) -> float:
        """Reference sphere radius, metres."""
        return float(self.body.radius)

    @property
    def frame(self) -> np.ndarray:
        """(3, 3) rows east, north, up at the centre, body-fixed unit vectors."""
        return enu_frame(self.center_lon, self.center_lat)

    @property
    def origin(self) -> np.ndarray:
        """Body-fixed XYZ (metres) of the local origin: the centre on the sphere, (3,)."""
        return self.radius * unit_vector(self.center_lon, self.center_lat)

    def to_body(self, points) -> np.ndarray:
        """Local points (..., 3) metres → body-fixed XYZ (..., 3) metres."""
        return self.origin + np.asarray(points, dtype=np.float64) @ self.frame

    def to_local(self, xyz) -> np.ndarray:
        """Body-fixed XYZ (..., 3) metres → local points (..., 3) metres."""
        return (np.asarray(xyz, dtype=np.float64) - self.origin) @ self.frame.T

    def directions_to_body(self, vectors) -> np.ndarray:
        """Local vectors (..., 3) → body-fixed vectors (rotation only)."""
        return np.asarray(vectors, dtype=np.float64) @ self.frame

    def directions_to_local(self, vectors) -> np.ndarray:
        """Body-fixed vectors (..., 3) → local vectors (rotation only)."""
        return np.asarray(vectors, dtype=np.float64) @ self.frame.T

    def sun_position(self, sun_vector_local) -> np.ndarray:
        """Body-fixed sun position (metres, (3,)) one au from the scene centre along the
        local unit vector ``sun_vector_local``, so the direction to it from the centre is
        exactly the scene's sun."""
        s = np.asarray(sun_vector_local, dtype=np.float64)
        return self.origin + SUN_DISTANCE_M * self.directions_to_body(s / np.linalg.norm(s))

    def tags(self) -> dict:
        """``scene.json`` / raster description of the placement."""
        return {**self.body.tags(), "center_lon_deg": self.center_lon,
                "center_lat_deg": self.center_lat,
                "local_frame": "east-north-up at the centre, origin on the reference sphere"}


def placement(body: str | Body = "Moon", center_lon: float = 0.0,
              center_lat: float = 0.0) -> Placement:
    """A :class:`Placement` on ``body`` (a :class:`Body` or a name PROJ knows).

    Raises
    ------
    ValueError
        Unknown body name, or a latitude outside [−90, 90].
    """
    if not -90.0 <= float(center_lat) <= 90.0:
        raise ValueError(f"centre latitude must lie in [-90, 90], got {center_lat}")
    try:
        the_body = body if isinstance(body, Body) else body_by_name(str(body))
    except KeyError as exc:
        raise ValueError(str(exc.args[0]) if exc.args else f"unknown body {body!r}") from None
    return Placement(the_body, float(center_lon), float(center_lat))


@njit(cache=True, nogil=True, error_model="numpy")
def _radial_heights(ux, uy, uz, radius, dem, x_first, y_first, spacing, iterations, out,
                    start, stop):
    """Distance s along unit local directions u from the body centre (0, 0, −R) to the
    height field, minus R, into ``out[start:stop]``; NaN outside the DEM or for
    directions away from the scene."""
    rows, cols = dem.shape
    for i in range(start, stop):
        if uz[i] <= 0.0:
            out[i] = np.nan
            continue
        s = radius / uz[i]
        for _ in range(iterations):
            fc = (s * ux[i] - x_first) / spacing
            fr = (y_first - s * uy[i]) / spacing
            if not (fc >= 0.0 and fr >= 0.0 and fc <= cols - 1 and fr <= rows - 1):
                s = np.nan
                break
            c0 = min(int(fc), cols - 2)
            r0 = min(int(fr), rows - 2)
            a = fc - c0
            b = fr - r0
            h = ((dem[r0, c0] * (1.0 - a) + dem[r0, c0 + 1] * a) * (1.0 - b)
                 + (dem[r0 + 1, c0] * (1.0 - a) + dem[r0 + 1, c0 + 1] * a) * b)
            s = (radius + h) / uz[i]
        out[i] = s - radius


def surface_height(place: Placement, field, lon_deg, lat_deg) -> np.ndarray:
    """Height of the scene's true surface above the reference sphere along radial lines.

    The radial line through (λ, φ) is ``s · u`` from the body centre, in local
    coordinates ``(0, 0, −R) + s u_local``; it meets the height field where
    ``−R + s u_z = h(s u_x, s u_y)``.  Fixed point ``s ← (R + h(s u_x, s u_y)) / u_z``
    (a contraction: |dh/ds| ≤ slope · |u_xy| / u_z ≈ slope · 1e-4), from s = R / u_z.
    h is the renderer's bilinear interpolation of the DEM
    (:func:`demtool.synth.render.height_field`), so this is the surface the images see.

    Parameters
    ----------
    place : Placement
    field : demtool.synth.render.HeightField
        The scene's terrain in the local frame.
    lon_deg, lat_deg : array_like (broadcastable), degrees
        Planetocentric, east-positive.

    Returns
    -------
    float64 array of the broadcast shape
        Radial height above the sphere of radius ``place.radius``, metres; NaN where
        the radial line leaves the DEM.
    """
    u = place.directions_to_local(unit_vector(lon_deg, lat_deg))
    shape = u.shape[:-1]
    flat = np.ascontiguousarray(u.reshape(-1, 3))
    from demtool.tiling.rows import on_row_parts

    ux, uy, uz = flat[:, 0].copy(), flat[:, 1].copy(), flat[:, 2].copy()
    heights = np.empty(flat.shape[0])
    on_row_parts(lambda start, stop: _radial_heights(
        ux, uy, uz, place.radius, field.dem, field.x_first, field.y_first, field.spacing,
        SURFACE_ITERATIONS, heights, start, stop), flat.shape[0])
    return heights.reshape(shape)


def local_heights(field, x, y) -> np.ndarray:
    """The renderer's bilinear height h(x, y) of the DEM at local points (NaN outside)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    fc = (x - field.x_first) / field.spacing
    fr = (field.y_first - y) / field.spacing
    rows, cols = field.dem.shape
    inside = (fc >= 0) & (fr >= 0) & (fc <= cols - 1) & (fr <= rows - 1)
    c0 = np.clip(np.floor(np.where(inside, fc, 0)).astype(np.int64), 0, cols - 2)
    r0 = np.clip(np.floor(np.where(inside, fr, 0)).astype(np.int64), 0, rows - 2)
    a, b = fc - c0, fr - r0
    d = field.dem
    h = ((d[r0, c0] * (1 - a) + d[r0, c0 + 1] * a) * (1 - b)
         + (d[r0 + 1, c0] * (1 - a) + d[r0 + 1, c0 + 1] * a) * b)
    return np.where(inside, h, np.nan)
