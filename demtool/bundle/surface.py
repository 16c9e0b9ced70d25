"""A reference DEM as ground control of a sensor block (``bundle --reference-dem``).

Tie points fix the shape of a block, not its datum: a similarity (3 translations, 3
rotations, a scale) of all sensors and points leaves every image unchanged, so with
pose priors alone the block sits where the priors' mean puts it.  Mapping teams tie
the block to a reference terrain instead (LOLA for the Moon, MOLA for Mars); ASP's
``bundle_adjust --heights-from-dem`` (and ``--reference-terrain``) does it by
constraining the tie points' heights to the DEM.  Here every tie point ``X`` gets one
more residual, its height above the body's reference sphere minus the DEM's height at
its longitude and latitude (bilinear),

    r(X) = (h(X) − h_DEM(lon(X), lat(X))) / σ_DEM,

with a Huber loss, so the block's height, tilt and scale follow the DEM, and where the
terrain has relief (slopes) its horizontal position and azimuth too: a horizontal
shift ``d`` of the block changes the residuals by ``∇h_DEM · d``.

:class:`ReferenceSurface` is pure (arrays in, arrays out): the DEM's heights (a window
around the block, held in memory), its map transform and CRS on the body's sphere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.mapproject import bilinear_heights
from demtool.maps import lonlat_to_map, wrap_longitude, xyz_to_lonlat_height

#: forward-difference step of the height residual's gradient, metres
GRADIENT_STEP_M = 0.01


@dataclass(frozen=True)
class ReferenceSurface:
    """A reference DEM on the body's map, for height residuals of body-fixed points.

    Attributes
    ----------
    heights : (H, W) float64
        Metres above the body's reference sphere (radial), NaN = no data.
    transform : affine.Affine
        Map transform of ``heights`` (pixel corner convention, as rasterio's).
    crs : pyproj.CRS
        The DEM's CRS on the body's sphere (projected, or geographic: x = lon, y = lat
        in degrees).
    radius : float
        The body's reference sphere radius, metres (heights of points are measured
        radially above it).
    sigma : float
        Standard deviation of the DEM's heights (and of its interpolation to a tie
        point), metres.
    """

    heights: np.ndarray
    transform: Any
    crs: Any
    radius: float
    sigma: float

    def dem_heights(self, xyz) -> np.ndarray:
        """DEM heights (metres above the sphere, bilinear) below body-fixed points
        (..., 3) metres; NaN off the DEM or on its no-data cells."""
        lon, lat, _ = xyz_to_lonlat_height(np.asarray(xyz, dtype=np.float64),
                                           radii=self.radius)
        if self.crs.is_geographic:
            t = self.transform
            x = wrap_longitude(lon, t.c + 0.5 * t.a * self.heights.shape[1])
            y = lat
        else:
            x, y = lonlat_to_map(self.crs, lon, lat)
        inv = ~self.transform
        col = inv.a * x + inv.b * y + inv.c - 0.5
        row = inv.d * x + inv.e * y + inv.f - 0.5
        good = np.isfinite(row) & np.isfinite(col)
        out = np.full(np.shape(row), np.nan)
        if np.any(good):
            out[good] = bilinear_heights(self.heights, row[good], col[good])
        return out

    def residuals(self, xyz) -> np.ndarray:
        """``h(X) − h_DEM(X)`` of body-fixed points (P, 3), metres; NaN off the DEM."""
        xyz = np.asarray(xyz, dtype=np.float64)
        _, _, height = xyz_to_lonlat_height(xyz, radii=self.radius)
        return height - self.dem_heights(xyz)

    def residuals_and_gradient(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Height residuals (P,) metres and their gradient (P, 3) with respect to the
        points (forward differences of :data:`GRADIENT_STEP_M`); NaN rows off the DEM."""
        xyz = np.asarray(xyz, dtype=np.float64)
        base = self.residuals(xyz)
        gradient = np.empty(xyz.shape)
        for k in range(3):
            moved = xyz.copy()
            moved[:, k] += GRADIENT_STEP_M
            gradient[:, k] = (self.residuals(moved) - base) / GRADIENT_STEP_M
        return base, gradient


def huber_weights(normalised: np.ndarray, threshold: float) -> np.ndarray:
    """IRLS weights of a Huber loss of residuals in sigma units (Huber 1964): 1 inside
    ``threshold``, ``threshold / |r|`` outside; 0 for NaN residuals (no DEM)."""
    r = np.abs(np.asarray(normalised, dtype=np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(r <= threshold, 1.0, threshold / r)
    return np.where(np.isfinite(r), w, 0.0)


def huber_cost(normalised: np.ndarray, threshold: float) -> float:
    """Σ ρ(r) of residuals in sigma units, ρ the Huber loss scaled as r² inside the
    threshold (NaN residuals count 0)."""
    r = np.abs(np.asarray(normalised, dtype=np.float64))
    r = r[np.isfinite(r)]
    return float(np.sum(np.where(r <= threshold, r ** 2, 2 * threshold * r - threshold ** 2)))


def surface_normal_equations(surface: ReferenceSurface, points: np.ndarray, *,
                             threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference DEM's share of the point blocks of the normal equations.

    Returns
    -------
    v : (P, 3, 3) float64
        ``w J Jᵀ / σ²`` to add to each point's block.
    g : (P, 3) float64
        ``−w J r / σ²`` to add to each point's gradient side.
    residuals : (P,) float64
        Height residuals, metres (NaN off the DEM).
    """
    r, jac = surface.residuals_and_gradient(points)
    w = huber_weights(r / surface.sigma, threshold) / surface.sigma ** 2
    jac = np.where(np.isfinite(jac), jac, 0.0)
    rr = np.where(np.isfinite(r), r, 0.0)
    v = w[:, None, None] * jac[:, :, None] * jac[:, None, :]
    g = -(w * rr)[:, None] * jac
    return v, g, r
