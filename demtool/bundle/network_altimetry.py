"""Laser altimetry shots as ground control of a control-network adjustment
(``bundle --control-network … --reference-points shots.csv``).

The shots (:mod:`demtool.io.altimetry`) define a surface: their heights above the body's
sphere, linearly interpolated on a local east/north plane (Delaunay triangles of the
shots, as a TIN), within ``reach`` of a shot (3 × the median spacing of consecutive
shots: between tracks farther apart nothing is known).  Each network point over that
surface gets one observation, its height minus the surface's at its current horizontal
position (so the block is pulled in height and, over slopes, sideways, as ASP's
``--heights-from-dem`` does with a DEM), with the sigma ``sqrt(σ_shot² + s²)``:
``σ_shot`` the shots' stated sigma (a ``sigma`` column) or the one given, ``s`` an
allowance for the ground between shots, 0.1 × the shots' height standard deviation ×
(the point's distance to the nearest shot / reach): zero on a shot, growing away from it
(a heuristic, not a measured interpolation error).
"""

from __future__ import annotations

import numpy as np


class ShotSurface:
    """The shots' surface (module docstring); ``radius``: the body's sphere, metres."""

    def __init__(self, shots, *, radius: float, sigma: float):
        from scipy.interpolate import LinearNDInterpolator
        from scipy.spatial import cKDTree

        from demtool.maps import lonlat_height_to_xyz

        shot_radius = shots.radius if shots.radius is not None else radius + shots.height
        self.radius = float(radius)
        heights = shot_radius - radius
        ground = lonlat_height_to_xyz(shots.lon, shots.lat, 0.0, radii=radius)
        centre = ground.mean(axis=0)
        self.up = centre / np.linalg.norm(centre)
        east = np.cross([0.0, 0.0, 1.0], self.up)
        if np.linalg.norm(east) < 1e-9:
            east = np.array([1.0, 0.0, 0.0])
        self.east = east / np.linalg.norm(east)
        self.north = np.cross(self.up, self.east)
        plane = self._plane(ground)
        order = np.argsort(shots.time) if shots.time is not None else np.arange(len(ground))
        steps = np.linalg.norm(np.diff(plane[order], axis=0), axis=1)
        positive = steps[steps > 0]
        self.reach = 3.0 * float(np.median(positive)) if len(positive) else 0.0
        self.tree = cKDTree(plane)
        self.surface = LinearNDInterpolator(plane, heights)
        stated = shots.sigma if shots.sigma is not None else np.full(len(heights), sigma)
        self.sigma_shot = float(np.median(stated))
        self.relief = float(np.std(heights))
        self.count = len(heights)

    def _plane(self, xyz) -> np.ndarray:
        foot = xyz / np.linalg.norm(xyz, axis=-1, keepdims=True) * self.radius
        return np.stack([foot @ self.east, foot @ self.north], axis=-1)

    def height_at(self, points) -> tuple[np.ndarray, np.ndarray]:
        """The surface's height (m above the sphere; NaN off it) under body-fixed points
        (P, 3), and its sigma."""
        plane = self._plane(np.asarray(points, dtype=np.float64))
        height = np.asarray(self.surface(plane), dtype=np.float64)
        distance, _ = self.tree.query(plane)
        height = np.where(distance <= self.reach, height, np.nan)
        spread = self.relief * np.minimum(distance / max(self.reach, 1e-9), 1.0) * 0.1
        return height, np.sqrt(self.sigma_shot ** 2 + spread ** 2)

    def residuals(self, points) -> tuple[np.ndarray, np.ndarray]:
        """(P,) point height minus the surface's (NaN off it) and (P,) sigmas, metres."""
        points = np.asarray(points, dtype=np.float64)
        height, sigma = self.height_at(points)
        return np.linalg.norm(points, axis=1) - self.radius - height, sigma

    def gradient(self, points, step: float = 0.5) -> np.ndarray:
        """(P, 3) derivative of :meth:`residuals` by the point (forward differences of
        ``step`` metres on the surface)."""
        points = np.asarray(points, dtype=np.float64)
        up = points / np.linalg.norm(points, axis=1, keepdims=True)
        base, _ = self.height_at(points)
        grad = up.copy()
        for axis in (self.east, self.north):
            moved, _ = self.height_at(points + step * axis)
            slope = np.nan_to_num((moved - base) / step)
            grad -= slope[:, None] * axis
        return grad
