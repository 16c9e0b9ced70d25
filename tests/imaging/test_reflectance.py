"""demtool.imaging.reflectance: lunar-Lambert and Lambert models."""

import numpy as np
import pytest

from demtool.imaging import reflectance as refl


def test_mcewen_L_values():
    assert refl.mcewen_L(0.0) == pytest.approx(1.0)
    # 1 - 0.019*60 + 2.42e-4*3600 - 1.46e-6*216000
    assert refl.mcewen_L(60.0) == pytest.approx(1 - 1.14 + 0.8712 - 0.31536)


def test_lunar_lambert_closed_form_and_limits():
    mu0, mu, phase = 0.5, 1.0, 60.0
    L = refl.mcewen_L(phase)
    expected = 0.12 * (2 * L * mu0 / (mu0 + mu) + (1 - L) * mu0)
    assert refl.lunar_lambert(mu0, mu, phase, 0.12) == pytest.approx(expected)
    assert refl.lunar_lambert(-0.1, 1.0, 30.0) == 0.0
    # L = 1 gives the Lommel-Seeliger law, L = 0 Lambert.
    assert refl.lunar_lambert(0.3, 0.9, 0.0) == pytest.approx(2 * 0.3 / 1.2)


def test_registry_and_sun_vector():
    assert refl.get_model("lambert")(np.array([0.5, -1.0]), 1.0, 0.0).tolist() == [0.5, 0.0]
    with pytest.raises(ValueError, match="should be one of lunar-lambert, lambert"):
        refl.get_model("hapke2")
    sun = refl.sun_vector(60.0, 90.0)  # from the east, 30 degrees above the horizon
    np.testing.assert_allclose(sun, [np.sin(np.radians(60)), 0, 0.5], atol=1e-12)
    assert refl.phase_angle_deg(sun, np.array([0, 0, 1.0])) == pytest.approx(60.0)
