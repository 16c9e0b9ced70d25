"""Tests of demtool.sgm.matcher helpers: the noise estimate behind the adaptive P2's κ."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.sgm.matcher import P2_KAPPA, P2_KAPPA_NOISE, noise_sigma, p2_kappa


@pytest.mark.parametrize("sigma", [0.5, 3.0, 10.0])
def test_noise_sigma_of_white_noise_on_a_smooth_image(sigma):
    rng = np.random.default_rng(1)
    rows, cols = np.mgrid[0:200, 0:240]
    smooth = 100 + 0.3 * cols + 20 * np.sin(rows / 30.0)  # planar-ish signal: cancelled
    image = smooth + rng.normal(0, sigma, smooth.shape)
    valid = np.ones(image.shape, bool)
    assert noise_sigma(image, valid) == pytest.approx(sigma, rel=0.08)


def test_noise_sigma_ignores_edges_and_invalid_pixels():
    rng = np.random.default_rng(2)
    image = np.where(np.arange(200)[None, :] % 40 < 20, 50.0, 200.0) * np.ones((150, 1))
    image = image + rng.normal(0, 2.0, image.shape)
    valid = np.ones(image.shape, bool)
    valid[:, :30] = False
    image[:, :30] = 1e6  # garbage where invalid
    assert noise_sigma(image, valid) == pytest.approx(2.0, rel=0.1)
    assert noise_sigma(image[:2], valid[:2]) == 0.0


def test_p2_kappa_grows_with_the_noise_only_above_the_floor():
    rng = np.random.default_rng(3)
    valid = np.ones((100, 100), bool)
    quiet = np.full((100, 100), 128.0) + rng.normal(0, 0.5, (100, 100))
    noisy = np.full((100, 100), 128.0) + rng.normal(0, 8.0, (100, 100))
    assert p2_kappa(quiet, valid) == P2_KAPPA
    assert p2_kappa(noisy, valid) == pytest.approx(P2_KAPPA_NOISE * 8.0, abs=2.5)
