"""Tests of demtool.imaging.spectral: radially averaged coherence and the coherent cut-off."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from demtool.errors import ProcessingError
from demtool.imaging.spectral import (
    coherence_cutoff,
    coherence_spectrum,
    cutoff_from_curve,
    largest_valid_rectangle,
    radial_coherence,
)


@pytest.fixture(scope="module")
def white() -> np.ndarray:
    return np.random.default_rng(1).normal(size=(256, 256))


def _gaussian_cutoff(sigma_px: float, noise_to_signal_power: float, spacing: float) -> float:
    """Frequency (cycles per unit) where H² P_a = P_n for a Gaussian low-pass of a white field.

    H(f) = exp(-2 π² σ² f²), so coherence H²/(H² + r) = 1/2 at H² = r.
    """
    sigma = sigma_px * spacing
    return float(np.sqrt(-np.log(noise_to_signal_power) / (4 * np.pi**2 * sigma**2)))


def test_identical_dems_are_fully_coherent(white):
    frequencies, coherence = radial_coherence(white, white.copy(), spacing=2.0)
    assert np.all(np.diff(frequencies) > 0)
    assert frequencies[0] > 0 and frequencies[-1] <= 0.25 + 1e-12
    np.testing.assert_allclose(coherence, 1.0, atol=1e-9)
    assert coherence_cutoff(white, white, spacing=2.0) == pytest.approx(0.25)


@pytest.mark.parametrize("sigma_px", [1.5, 3.0])
@pytest.mark.parametrize("spacing", [1.0, 2.5])
def test_gaussian_lowpass_cutoff_matches_analytic_frequency(white, sigma_px, spacing):
    rng = np.random.default_rng(7)
    noise_std = 0.1  # signal variance 1 -> noise-to-signal power 0.01
    smoothed = gaussian_filter(white, sigma_px, mode="wrap")
    dem = smoothed + rng.normal(scale=noise_std, size=white.shape)
    expected = _gaussian_cutoff(sigma_px, noise_std**2, spacing)
    found = coherence_cutoff(dem, white, spacing=spacing)
    # 8 %: sigma 1.5 vs 3.0 differ by a factor 2, a wrong unit by 2.5.
    assert found == pytest.approx(expected, rel=0.08)
    frequencies, coherence = radial_coherence(dem, white, spacing=spacing)
    assert np.all(coherence[frequencies < 0.5 * expected] > 0.8)
    assert np.all(coherence[frequencies > 1.6 * expected] < 0.2)


def test_independent_fields_are_incoherent(white):
    other = np.random.default_rng(2).normal(size=white.shape)
    spectrum = coherence_spectrum(other, white)
    assert np.median(spectrum.coherence) < 0.05
    assert coherence_cutoff(other, white) < 0.02


def test_nan_holes_are_cropped_or_filled(white):
    holed = white.copy()
    holed[:40, :] = np.nan  # a band of holes: the crop keeps rows 40..256
    spectrum = coherence_spectrum(holed, white, nan_policy="auto")
    assert spectrum.window == (40, 0, 256, 256)
    np.testing.assert_allclose(spectrum.coherence, 1.0, atol=1e-9)
    scattered = white.copy()
    scattered[np.random.default_rng(3).random(white.shape) < 0.02] = np.nan
    filled = coherence_spectrum(scattered, white, nan_policy="auto")
    assert filled.window == (0, 0, 256, 256)  # scattered holes: no large clean window
    np.testing.assert_allclose(filled.coherence, 1.0, atol=1e-9)


def test_power_spectrum_of_white_noise_is_its_variance(white):
    spectrum = coherence_spectrum(white, white, spacing=1.0, window="hann")
    # PSD of unit white noise with unit spacing integrates to 1 over [-0.5, 0.5]²
    assert np.median(spectrum.power_dem) == pytest.approx(1.0, rel=0.1)


def test_largest_valid_rectangle():
    valid = np.ones((50, 60), bool)
    valid[10:20, 5:30] = False
    assert largest_valid_rectangle(valid) == (20, 0, 50, 60)
    assert largest_valid_rectangle(np.zeros((4, 4), bool)) == (0, 0, 0, 0)


def test_cutoff_from_curve_interpolates_first_crossing():
    freq = np.array([0.1, 0.2, 0.3, 0.4])
    assert cutoff_from_curve(freq, np.array([0.9, 0.7, 0.3, 0.8])) == pytest.approx(0.25)
    assert cutoff_from_curve(freq, np.array([0.4, 0.9, 0.9, 0.9])) == 0.0


def test_bad_inputs(white):
    with pytest.raises(ValueError, match="one shape"):
        radial_coherence(white, white[:100])
    with pytest.raises(ProcessingError, match="too few common valid pixels"):
        radial_coherence(np.full((64, 64), np.nan), np.zeros((64, 64)))
    ramp = np.add.outer(np.arange(64.0), np.arange(64.0))
    with pytest.raises(ProcessingError, match="plane"):
        radial_coherence(ramp, white[:64, :64])
    with pytest.raises(ValueError, match="threshold"):
        coherence_cutoff(white, white, threshold=1.5)


@pytest.mark.parametrize("length", [0, 1, 2, 3, 7, 64, 255, 256, 1001])
def test_windows_are_scipys_value_for_value(length):
    """The tapers without scipy.signal's import: the same floats as scipy's windows."""
    from scipy.signal import windows

    from demtool.imaging.spectral import periodic_hann, periodic_tukey

    assert np.array_equal(periodic_hann(length), windows.hann(length, sym=False))
    for alpha in (0.0, 0.1, 0.25, 0.5, 0.99, 1.0, 1.5):
        assert np.array_equal(periodic_tukey(length, alpha),
                              windows.tukey(length, alpha, sym=False))
