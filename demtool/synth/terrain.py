"""Synthetic planetary terrain: fractal surface, simple craters, boulders, albedo.

Every function is pure (arrays in, arrays out) and seeded through a
:class:`numpy.random.Generator`, so the same generator state gives the same terrain.
Heights are metres; arrays are on the map grid (row 0 = northern edge, column 0 =
western edge, see CONTRIBUTING.md), cell centres ``spacing_m`` apart.
"""

from __future__ import annotations

import numpy as np


def fractal_surface(size: int, spacing_m: float, *, spectral_exponent: float,
                    rms_m: float, rng: np.random.Generator) -> np.ndarray:
    """Fractal (self-affine) surface by spectral synthesis.

    White Gaussian noise is filtered in the Fourier domain so that the power spectrum
    follows ``P(k) ∝ k^-β`` (random phases, Rayleigh amplitudes), the method of
    Saupe (1988), *Algorithms for random fractals*, in Peitgen & Saupe (eds.),
    *The Science of Fractal Images*, §2.4.  For a 2-D surface β = 2H + 2 with H the
    Hurst exponent (β = 3 ↔ H = 0.5, Brownian relief; lunar topography at metre to
    hectometre scales has H ≈ 0.7–0.9, β ≈ 3.4–3.8).

    Parameters
    ----------
    size : int
        Number of cells along each side.
    spacing_m : float
        Cell size in metres (sets the frequency axis; the result does not depend on it
        beyond scaling).
    spectral_exponent : float
        β, the power-law exponent of the 2-D power spectrum.
    rms_m : float
        Root-mean-square height of the result, metres (0 gives a flat surface).
    rng : numpy.random.Generator
        Source of the random phases.

    Returns
    -------
    (size, size) float64
        Heights in metres, mean 0, standard deviation ``rms_m``; periodic.
    """
    noise = rng.standard_normal((size, size))
    if rms_m == 0.0:
        return np.zeros((size, size))
    frequency = np.fft.fftfreq(size, d=spacing_m)
    k = np.hypot(frequency[:, None], frequency[None, :])
    k[0, 0] = np.inf  # drop the mean
    spectrum = np.fft.fft2(noise) * k ** (-spectral_exponent / 2.0)
    surface = np.fft.ifft2(spectrum).real
    surface -= surface.mean()
    std = surface.std()
    return surface * (rms_m / std) if std > 0 else surface


def crater_diameters(count: int, *, min_diameter_m: float, max_diameter_m: float,
                     exponent: float, rng: np.random.Generator) -> np.ndarray:
    """Crater diameters drawn from a truncated cumulative power law ``N(>D) ∝ D^-b``.

    Inverse-transform sampling of the size–frequency distribution between
    ``min_diameter_m`` and ``max_diameter_m``; b ≈ 2 is the empirical equilibrium
    slope of small lunar craters (Gault 1970; Melosh 1989, *Impact Cratering*, §11.3).

    Returns
    -------
    (count,) float64
        Diameters in metres, sorted from largest to smallest (large craters are
        placed first, so small ones overprint them).
    """
    u = rng.random(count)
    a, b = min_diameter_m ** (-exponent), max_diameter_m ** (-exponent)
    diameters = (a - u * (a - b)) ** (-1.0 / exponent)
    return np.sort(diameters)[::-1]


def crater_profile(r_over_radius: np.ndarray, *, depth_ratio: float, rim_ratio: float,
                   diameter_m: float) -> np.ndarray:
    """Height change of a fresh simple crater as a function of normalised radius.

    Bowl: a paraboloid from the floor (``depth`` below the rim crest) to the rim crest
    (``rim`` above the pre-impact surface) at r = R.  Outside, the rim and ejecta
    blanket fall off as (r/R)^-3 (McGetchin, Settle & Head 1973, ejecta thickness),
    shifted so the profile reaches 0 at r = 3R.  Proportions after Pike (1977),
    *Size-dependence in the shape of fresh impact craters on the Moon*: depth ≈ 0.2 D
    and rim height ≈ 0.04 D for simple craters.

    Parameters
    ----------
    r_over_radius : array
        Distance from the crater centre divided by the crater radius.
    depth_ratio : float
        Rim-crest-to-floor depth divided by the diameter.
    rim_ratio : float
        Rim-crest height above the surroundings divided by the diameter.
    diameter_m : float
        Rim-crest diameter D in metres.

    Returns
    -------
    array
        Height change in metres (same shape as ``r_over_radius``).
    """
    rho = np.asarray(r_over_radius, dtype=np.float64)
    depth = depth_ratio * diameter_m
    rim = rim_ratio * diameter_m
    inside = rim - depth + depth * rho**2
    cutoff = 3.0 ** -3
    with np.errstate(divide="ignore"):
        outside = rim * (np.maximum(rho, 1.0) ** -3 - cutoff) / (1.0 - cutoff)
    return np.where(rho <= 1.0, inside, np.where(rho < 3.0, outside, 0.0))


def add_craters(dem: np.ndarray, spacing_m: float, diameters_m: np.ndarray, *,
                depth_ratio: float, rim_ratio: float,
                rng: np.random.Generator) -> np.ndarray:
    """Superpose simple craters (:func:`crater_profile`) at uniformly random places.

    Parameters
    ----------
    dem : (H, W) float
        Pre-impact heights, metres (not modified).
    spacing_m : float
        Cell size, metres.
    diameters_m : (N,) float
        Crater diameters in metres, in the order they are emplaced.

    Returns
    -------
    (H, W) float64
        Heights with the craters added.
    """
    out = np.array(dem, dtype=np.float64, copy=True)
    height, width = out.shape
    centres = rng.random((len(diameters_m), 2)) * [width, height]  # in cells
    for (cx, cy), diameter in zip(centres, diameters_m, strict=True):
        radius_cells = 0.5 * diameter / spacing_m
        reach = int(np.ceil(3.0 * radius_cells)) + 1
        c0, c1 = max(0, int(cx) - reach), min(width, int(cx) + reach + 1)
        r0, r1 = max(0, int(cy) - reach), min(height, int(cy) + reach + 1)
        if c0 >= c1 or r0 >= r1:
            continue
        cols = np.arange(c0, c1) + 0.5
        rows = np.arange(r0, r1) + 0.5
        rho = np.hypot(cols[None, :] - cx, rows[:, None] - cy) / radius_cells
        out[r0:r1, c0:c1] += crater_profile(rho, depth_ratio=depth_ratio, rim_ratio=rim_ratio,
                                            diameter_m=diameter)
    return out


def add_boulders(dem: np.ndarray, spacing_m: float, count: int, *, mean_height_m: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Scatter boulders as Gaussian bumps (height exponentially distributed, σ = height).

    Parameters
    ----------
    dem : (H, W) float
        Heights, metres (not modified).
    count : int
        Number of boulders.
    mean_height_m : float
        Mean boulder height, metres; each boulder's Gaussian width σ equals its height
        (but at least one cell), so boulders are about twice as wide as high.

    Returns
    -------
    (H, W) float64
        Heights with the boulders added.
    """
    out = np.array(dem, dtype=np.float64, copy=True)
    height, width = out.shape
    centres = rng.random((count, 2)) * [width, height]
    heights = rng.exponential(mean_height_m, count)
    for (cx, cy), h in zip(centres, heights, strict=True):
        sigma_cells = max(h / spacing_m, 1.0)
        reach = int(np.ceil(4.0 * sigma_cells))
        c0, c1 = max(0, int(cx) - reach), min(width, int(cx) + reach + 1)
        r0, r1 = max(0, int(cy) - reach), min(height, int(cy) + reach + 1)
        cols = np.arange(c0, c1) + 0.5
        rows = np.arange(r0, r1) + 0.5
        r2 = (cols[None, :] - cx) ** 2 + (rows[:, None] - cy) ** 2
        out[r0:r1, c0:c1] += h * np.exp(-0.5 * r2 / sigma_cells**2)
    return out


def albedo_map(size: int, spacing_m: float, *, mean: float, variation: float,
               correlation_m: float, rng: np.random.Generator) -> np.ndarray:
    """Low-frequency albedo field ``ρ = mean · (1 + variation · f)`` with ``max |f| = 1``.

    ``f`` is white noise low-pass filtered with a Gaussian of standard deviation
    ``correlation_m`` (in the Fourier domain, periodic), scaled so its extreme value is
    ±1: the albedo spans exactly ``mean · (1 ± variation)``.

    Returns
    -------
    (size, size) float64
        Normal albedo ρ (dimensionless), on the map grid.
    """
    noise = rng.standard_normal((size, size))
    if variation == 0.0:
        return np.full((size, size), float(mean))
    frequency = np.fft.fftfreq(size, d=spacing_m)
    k2 = frequency[:, None] ** 2 + frequency[None, :] ** 2
    smooth = np.fft.ifft2(np.fft.fft2(noise) * np.exp(-2.0 * np.pi**2 * correlation_m**2 * k2)).real
    smooth -= smooth.mean()
    peak = np.abs(smooth).max()
    field = smooth / peak if peak > 0 else smooth
    return mean * (1.0 + variation * field)
