"""Spring-metaphor gap filling (D'Errico's inpaint_nans, method 4)."""

import numpy as np
import pytest

from demtool.errors import ProcessingError
from demtool.imaging.interpolate import inpaint_springs, spring_system


def plane(height: int, width: int) -> np.ndarray:
    rows, cols = np.mgrid[:height, :width]
    return 0.37 * cols - 0.21 * rows + 12.5


def test_linear_surface_reproduced_exactly_in_enclosed_gaps():
    truth = plane(60, 80)
    values = truth.copy()
    values[10:40, 15:50] = np.nan  # a large hole
    rng = np.random.default_rng(1)
    scattered = rng.random(values.shape) < 0.4
    scattered[[0, -1], :] = False  # keep the border measured: the gaps are enclosed
    scattered[:, [0, -1]] = False
    values[scattered] = np.nan
    filled = inpaint_springs(values)
    assert filled.dtype == np.float64
    np.testing.assert_allclose(filled, truth, rtol=0, atol=1e-9)


def test_linear_surface_exact_with_iterative_solver():
    truth = plane(120, 100)
    values = truth.copy()
    rng = np.random.default_rng(2)
    gaps = rng.random(values.shape) < 0.97  # sparse measurements, like splatted points
    gaps[[0, -1], :] = False
    gaps[:, [0, -1]] = False
    values[gaps] = np.nan
    # Force the multigrid-preconditioned CG path on a small grid.
    filled = inpaint_springs(values, direct_max_unknowns=100)
    np.testing.assert_allclose(filled, truth, rtol=0, atol=1e-6)
    direct = inpaint_springs(values)
    np.testing.assert_allclose(filled, direct, rtol=0, atol=1e-6)


def test_measured_cells_unchanged_and_input_not_modified():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(40, 50)) * 10
    values[rng.random(values.shape) < 0.6] = np.nan
    original = values.copy()
    filled = inpaint_springs(values)
    measured = np.isfinite(original)
    assert np.array_equal(filled[measured], original[measured])  # bit for bit
    assert np.isfinite(filled).all()
    np.testing.assert_array_equal(values, original)  # input untouched (NaNs included)
    # Discrete maximum principle: the fill stays within the measured range.
    assert filled.min() >= original[measured].min() - 1e-9
    assert filled.max() <= original[measured].max() + 1e-9


def test_filled_values_satisfy_the_spring_equilibrium():
    """Each filled cell is the mean of its in-grid neighbours (zero net spring force)."""
    rng = np.random.default_rng(4)
    values = rng.normal(size=(30, 30))
    values[5:25, 8:20] = np.nan
    values[0, :10] = np.nan  # a gap on the edge: free boundary there
    filled = inpaint_springs(values)
    A, rhs, unknown = spring_system(values)
    np.testing.assert_allclose(A @ filled[unknown], rhs, atol=1e-9)
    r, c = 0, 4  # edge cell: three neighbours
    assert filled[r, c] == pytest.approx(
        (filled[r, c - 1] + filled[r, c + 1] + filled[r + 1, c]) / 3)


def test_single_measurement_gives_constant():
    values = np.full((9, 7), np.nan)
    values[4, 3] = 2.5
    np.testing.assert_allclose(inpaint_springs(values), 2.5)


def test_complete_grid_returned_as_copy():
    values = plane(5, 6)
    filled = inpaint_springs(values)
    assert filled is not values
    np.testing.assert_array_equal(filled, values)


def test_all_nan_is_a_clear_error():
    with pytest.raises(ProcessingError, match="no measured"):
        inpaint_springs(np.full((8, 8), np.nan))


def test_infinite_values_are_gaps_and_wrong_shape_is_rejected():
    truth = plane(20, 20)
    values = truth.copy()
    values[8:12, 8:12] = np.inf
    np.testing.assert_allclose(inpaint_springs(values), truth, atol=1e-9)
    with pytest.raises(ValueError, match="2-D"):
        inpaint_springs(np.zeros(5))
