"""demtool.sensors.natural_spline equals SciPy's natural CubicSpline to the bit."""

import numpy as np
import pytest

from demtool.sensors.isd import resample_states
from demtool.sensors.natural_spline import natural_cubic_spline

interpolate = pytest.importorskip("scipy.interpolate")


@pytest.mark.parametrize("spacing", ["even", "random", "pivoting"])
def test_equals_scipy_cubic_spline_to_the_bit(spacing):
    rng = np.random.default_rng(7)
    for _ in range(40):
        n = int(rng.integers(3, 40))
        if spacing == "even":  # an ephemeris: seconds around a large epoch
            x = 3.0e8 + np.arange(n) * 0.25
        elif spacing == "random":
            x = np.cumsum(rng.uniform(0.01, 5.0, n))
        else:  # steps 1000x apart: dgtsv interchanges rows
            x = np.cumsum(rng.choice([0.001, 1.0, 100.0], n))
        y = rng.normal(0.0, 1.0, (n, 3)) * 10 ** rng.uniform(-3, 7) + rng.normal(0, 1e6, 3)
        span = x[-1] - x[0]
        at = np.concatenate([rng.uniform(x[0] - 0.2 * span, x[-1] + 0.2 * span, 64), x])
        expected = interpolate.CubicSpline(x, y, bc_type="natural", axis=0)(at)
        assert natural_cubic_spline(x, y, at).tobytes() == expected.tobytes()


def test_resample_states_without_velocities_is_scipy_natural_spline():
    times = np.array([0.0, 0.5, 2.0, 2.25, 4.0])
    positions = np.array([[1.0, 2.0, 3.0], [2.0, -1.0, 0.5], [0.0, 4.0, 1.0],
                          [3.0, 3.0, 3.0], [-1.0, 0.0, 2.0]]) * 1.7e6
    grid = np.linspace(-0.5, 4.5, 41)
    expected = interpolate.CubicSpline(times, positions, bc_type="natural", axis=0)(grid)
    assert resample_states(times, positions, None, grid).tobytes() == expected.tobytes()


def test_natural_ends_and_refusals():
    x = np.array([0.0, 1.0, 3.0, 4.0])
    y = np.column_stack([x ** 3, x])
    at = np.array([0.0, 4.0])
    h = 1e-4  # second differences at the ends: zero for a natural spline
    for end in at:
        values = natural_cubic_spline(x, y, [end - h, end, end + h])
        assert abs(values[0, 0] - 2 * values[1, 0] + values[2, 0]) / h ** 2 < 1e-4
    with pytest.raises(ValueError, match="n >= 3"):
        natural_cubic_spline(x[:2], y[:2], at)
