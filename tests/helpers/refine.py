"""Small synthetic scenes with known truth for the `refine` tests (no dependency on synth).

The renderer here is deliberately independent of :mod:`demtool.refine.shading`: normals
from ``numpy.gradient`` and the lunar-Lambert function of :mod:`demtool.imaging.reflectance`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from demtool.imaging.reflectance import lunar_lambert, phase_angle_deg


def sun_vector(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector toward the sun, grid frame (azimuth clockwise from image up)."""
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)])


def render(dem: np.ndarray, spacing: float, sun: np.ndarray, albedo=1.0,
           view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Lunar-Lambert image of ``dem`` (rows down, y up), no shadows."""
    dz_drow, dz_dcol = np.gradient(dem, spacing)
    p, q = dz_dcol, -dz_drow
    norm = np.sqrt(1 + p**2 + q**2)
    view = np.asarray(view, dtype=float)
    mu0 = (sun[2] - p * sun[0] - q * sun[1]) / norm
    mu = (view[2] - p * view[0] - q * view[1]) / norm
    return lunar_lambert(mu0, mu, phase_angle_deg(sun, view), albedo).astype(np.float32)


def paraboloid_hills(size: int = 128, spacing: float = 1.0, seed: int = 3) -> np.ndarray:
    """Paraboloid domes and bowls of 4–12 px radius (heights ≤ ~0.35 radius) on a tilt."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:size, 0:size].astype(float)
    dem = 0.02 * cols * spacing - 0.01 * rows * spacing
    for _ in range(size * size // 250):
        r0, c0 = rng.uniform(0, size, 2)
        radius = rng.uniform(4, 12)
        height = rng.uniform(-0.35, 0.35) * radius
        d2 = ((rows - r0) ** 2 + (cols - c0) ** 2) / radius**2
        dem += np.where(d2 < 1, height * (1 - d2), 0.0) * spacing
    return ndimage.gaussian_filter(dem, 1.0)  # round the paraboloids' rims a little


@dataclass
class Scene:
    truth: np.ndarray
    coarse: np.ndarray
    image: np.ndarray
    albedo: np.ndarray
    sun: np.ndarray
    spacing: float


def hills_scene(size: int = 128, spacing: float = 1.0, *, elevation: float = 35.0,
                azimuth: float = 120.0, smoothing: float = 6.0, noise: float = 0.005,
                albedo_variation: float = 0.0, dn_scale: float = 800.0,
                seed: int = 3) -> Scene:
    """Paraboloid hills rendered with lunar-Lambert; the coarse DEM is the truth smoothed.

    ``albedo_variation`` is the amplitude of a smooth relative albedo field (wavelengths
    300 and 350 px); the image is in
    DN (``dn_scale`` per unit reflectance) with Gaussian noise of ``noise`` (relative).
    """
    rng = np.random.default_rng(seed)
    truth = paraboloid_hills(size, spacing, seed)
    sun = sun_vector(azimuth, elevation)
    rows, cols = np.mgrid[0:size, 0:size].astype(float)
    field = np.sin(2 * np.pi * cols / 300 + 0.5) * np.cos(2 * np.pi * rows / 350 - 0.3)
    albedo = (1.0 + albedo_variation * field).astype(np.float32)
    image = render(truth, spacing, sun, albedo) * dn_scale
    image = image * (1 + noise * rng.normal(size=image.shape))
    coarse = ndimage.gaussian_filter(truth, smoothing)
    return Scene(truth=truth, coarse=coarse, image=image.astype(np.float32),
                 albedo=albedo * dn_scale, sun=sun, spacing=spacing)


def rmse(a: np.ndarray, b: np.ndarray, margin: int = 0) -> float:
    """RMS difference, optionally without a border of ``margin`` pixels."""
    d = np.asarray(a, float) - np.asarray(b, float)
    if margin:
        d = d[margin:-margin, margin:-margin]
    return float(np.sqrt(np.mean(d**2)))


def slope_error(a: np.ndarray, b: np.ndarray, spacing: float, margin: int = 0) -> float:
    """RMS of the difference of the gradient vectors (metres per metre)."""
    ar, ac = np.gradient(np.asarray(a, float), spacing)
    br, bc = np.gradient(np.asarray(b, float), spacing)
    e = (ar - br) ** 2 + (ac - bc) ** 2
    if margin:
        e = e[margin:-margin, margin:-margin]
    return float(np.sqrt(np.mean(e)))
