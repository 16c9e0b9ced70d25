"""Synthetic DEMs with known truth for the compare tests."""

from __future__ import annotations

import numpy as np


def fractal(size: int, *, beta: float = 4.0, relief: float = 20.0, seed: int = 0) -> np.ndarray:
    """Periodic fractal surface (power spectrum ∝ k^-β), peak-to-peak ``relief`` metres."""
    rng = np.random.default_rng(seed)
    frequency = np.fft.fftfreq(size)
    k = np.hypot(frequency[:, None], frequency[None, :])
    k[0, 0] = np.inf
    surface = np.fft.ifft2(np.fft.fft2(rng.standard_normal((size, size))) * k ** (-beta / 2)).real
    return surface / np.ptp(surface) * relief


def fourier_shift(surface: np.ndarray, dx_px: float, dy_px: float) -> np.ndarray:
    """Exact sub-pixel translation of a periodic surface: out[y, x] = surface[y − dy, x − dx].

    Independent of demtool's cubic-convolution shift (a phase ramp in the Fourier domain).
    """
    rows, cols = surface.shape
    fy = np.fft.fftfreq(rows)[:, None]
    fx = np.fft.fftfreq(cols)[None, :]
    ramp = np.exp(-2j * np.pi * (fx * dx_px + fy * dy_px))
    return np.fft.ifft2(np.fft.fft2(surface) * ramp).real


def wavy(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth analytic surface (metres) of map coordinates (metres)."""
    return 6.0 * np.sin(x / 37.0) * np.cos(y / 23.0) + 4.0 * np.sin((x + 0.5 * y) / 17.0)
