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


def test_nmad_with_the_median_given_is_the_same_number():
    rng = np.random.default_rng(3)
    for size in (1, 2, 7, 1000, 1001):
        values = rng.standard_t(3, size=size) * 5.0
        assert nmad(values, median=float(np.median(values))) == nmad(values)
