"""demtool.imaging.robust: the NMAD every stage and the comparison report use."""

import numpy as np
import pytest

from demtool.imaging.robust import nmad


def test_nmad_estimates_the_standard_deviation_of_gaussian_scatter():
    values = np.random.default_rng(0).normal(3.0, 2.0, 200_000)
    assert nmad(values) == pytest.approx(2.0, rel=0.01)


def test_nmad_ignores_a_minority_of_blunders():
    values = np.random.default_rng(1).normal(0.0, 1.0, 10_000)
    values[:500] = 1e6
    assert nmad(values) == pytest.approx(1.0, rel=0.1)
    assert nmad(np.array([1.0, 2.0, 3.0])) == pytest.approx(1.4826)
