"""Small synthetic stereo scenes with known truth, for the features/rectify/select tests.

A textured height field (band-pass noise albedo on smooth hills) is rendered by ray
casting from pinhole cameras made with :func:`demtool.sensors.pinhole.look_at`; the surface
has relief, so the epipolar geometry of two views is well defined (a plane would be
a degenerate configuration for the fundamental matrix).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from demtool.sensors.pinhole import PinholeCamera, look_at


@dataclass(frozen=True)
class Terrain:
    """A height field and albedo on a square world grid centred at the origin."""

    height: np.ndarray  # (n, n) float32 metres
    albedo: np.ndarray  # (n, n) float32
    spacing: float  # metres per grid cell
    half_extent: float  # grid covers [-half_extent, half_extent] in X and Y

    def _grid_coords(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # column from X (east), row from Y (north, row 0 = northern edge)
        col = (x + self.half_extent) / self.spacing
        row = (self.half_extent - y) / self.spacing
        return col.astype(np.float32), row.astype(np.float32)

    def sample(self, field: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        col, row = self._grid_coords(x, y)
        return cv2.remap(field, col, row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)

    def surface_points(self, count: int, rng: np.random.Generator,
                       margin: float = 0.3) -> np.ndarray:
        """Random surface points (count, 3) away from the grid edge."""
        xy = rng.uniform(-self.half_extent * (1 - margin), self.half_extent * (1 - margin),
                         (count, 2))
        z = self.sample(self.height, xy[:, 0:1].copy(), xy[:, 1:2].copy())[:, 0]
        return np.column_stack([xy, z])


def band_pass_noise(n: int, rng: np.random.Generator, sigmas=(1.0, 2.5, 6.0)) -> np.ndarray:
    """Texture: a sum of Gaussian-filtered white noises, normalised to zero mean, unit std."""
    total = np.zeros((n, n), np.float32)
    for sigma in sigmas:
        layer = cv2.GaussianBlur(rng.standard_normal((n, n)).astype(np.float32), (0, 0), sigma)
        total += layer / layer.std()
    return (total - total.mean()) / total.std()


def make_terrain(n: int = 768, spacing: float = 1.0, relief: float = 60.0,
                 seed: int = 0) -> Terrain:
    """Smooth hills with ``relief`` metres of amplitude and a band-pass albedo texture."""
    rng = np.random.default_rng(seed)
    hills = cv2.GaussianBlur(rng.standard_normal((n, n)).astype(np.float32), (0, 0), n / 24)
    hills = hills / np.abs(hills).max() * relief
    albedo = 0.5 + 0.12 * band_pass_noise(n, rng)
    return Terrain(hills.astype(np.float32), albedo.astype(np.float32), spacing,
                   0.5 * n * spacing)


def render(terrain: Terrain, camera: PinholeCamera, *, dn_scale: float = 3000.0,
           noise_dn: float = 4.0, seed: int = 0) -> np.ndarray:
    """Ray-cast the textured height field: (H, W) float32 DN (12-bit-like range)."""
    shape = (camera.height, camera.width)
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    rays = camera.rays(np.column_stack([u.ravel(), v.ravel()]))
    rays = rays.reshape(*shape, 3)
    centre = camera.center
    z = np.zeros(shape)
    for _ in range(25):  # fixed-point intersection with z = h(x, y)
        s = (z - centre[2]) / rays[..., 2]
        x = centre[0] + s * rays[..., 0]
        y = centre[1] + s * rays[..., 1]
        z = terrain.sample(terrain.height, x, y).astype(np.float64)
    albedo = terrain.sample(terrain.albedo, x, y)
    rng = np.random.default_rng(seed)
    image = albedo * dn_scale
    image = image + rng.normal(0.0, noise_dn, image.shape)
    return image.astype(np.float32)


@dataclass(frozen=True)
class StereoScene:
    terrain: Terrain
    left_camera: PinholeCamera
    right_camera: PinholeCamera
    left: np.ndarray
    right: np.ndarray


def make_camera(position, *, focal_px: float = 500.0, size: int = 320,
                target=(0.0, 0.0, 0.0)) -> PinholeCamera:
    return look_at(position, target, (0, 1, 0), focal_px=focal_px, width=size, height=size)


def make_stereo_scene(size: int = 320, baseline: float = 120.0, altitude: float = 600.0,
                      seed: int = 0) -> StereoScene:
    """Two views of the terrain: nadir-ish left, right shifted east with ~11° convergence."""
    terrain = make_terrain(seed=seed)
    left_camera = make_camera((-0.5 * baseline * 0.2, 10.0, altitude), size=size)
    right_camera = make_camera((baseline, -15.0, altitude * 0.97), size=size,
                               target=(5.0, 3.0, 0.0))
    left = render(terrain, left_camera, seed=seed + 1)
    right = render(terrain, right_camera, seed=seed + 2)
    return StereoScene(terrain, left_camera, right_camera, left, right)
