"""The splatting moments kernel (demtool.dem.grid_kernels) against its numpy formulation."""

import numpy as np

from demtool.dem.grid_kernels import bilinear_moments, cell_medians


def numpy_moments(x, y, z, shape):
    """What splat_bilinear summed before: 36 np.bincount images."""
    height, width = shape
    size = height * width
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    moments = np.zeros((9, size))
    for step_x, step_y, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                              (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        cols, rows = x0 + step_x, y0 + step_y
        ok = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height) & (w > 0)
        cells = rows[ok] * width + cols[ok]
        wk, dx, dy, zk = w[ok], (fx - step_x)[ok], (fy - step_y)[ok], z[ok]
        for i, term in enumerate((wk, wk * dx, wk * dy, wk * dx * dx, wk * dx * dy,
                                  wk * dy * dy, wk * zk, wk * zk * dx, wk * zk * dy)):
            moments[i] += np.bincount(cells, weights=term, minlength=size)
    return moments


def test_equal_to_the_bincount_formulation_bit_for_bit():
    rng = np.random.default_rng(0)
    for _ in range(20):
        height, width = (int(v) for v in rng.integers(1, 40, 2))
        count = int(rng.integers(0, 3000))
        # inside, on the edges, outside, on integer positions (zero weights)
        x = rng.uniform(-2.0, width + 1.0, count)
        y = rng.uniform(-2.0, height + 1.0, count)
        whole = rng.random(count) < 0.2
        x[whole], y[whole] = np.round(x[whole]), np.round(y[whole])
        z = rng.normal(size=count) * 10.0 ** rng.uniform(-3, 4)
        found = bilinear_moments(x, y, z, (height, width))
        assert np.array_equal(found, numpy_moments(x, y, z, (height, width)))


def test_one_sample_spreads_its_bilinear_weights():
    moments = bilinear_moments(np.array([1.25]), np.array([0.5]), np.array([2.0]), (2, 3))
    weights = moments[0].reshape(2, 3)
    assert np.allclose(weights, [[0.0, 0.375, 0.125], [0.0, 0.375, 0.125]])
    assert np.allclose(moments[6], 2.0 * moments[0])  # Σ w z = z Σ w
    # offsets sample − cell centre: +0.25 from column 1, −0.75 from column 2
    assert np.allclose(moments[1].reshape(2, 3)[0], [0.0, 0.375 * 0.25, 0.125 * -0.75])


def lexsort_medians(cells, values, size):
    """What splat_median computed before: a lexsort of all samples by (cell, value)."""
    grid = np.full(size, np.nan)
    order = np.lexsort((values, cells))
    sorted_cells, sorted_values = cells[order], values[order]
    starts = np.flatnonzero(np.r_[True, sorted_cells[1:] != sorted_cells[:-1]])
    sizes = np.diff(np.r_[starts, len(sorted_cells)])
    lower = sorted_values[starts + (sizes - 1) // 2]
    upper = sorted_values[starts + sizes // 2]
    grid[sorted_cells[starts]] = 0.5 * (lower + upper)
    return grid


def test_cell_medians_equal_the_lexsort_formulation_bit_for_bit():
    rng = np.random.default_rng(1)
    for size, count in ((1, 5), (50, 0), (50, 1), (400, 3000), (30, 5000), (3, 5000)):
        # few samples a cell, and cells of over 64 samples (sorted runs merged: 30 cells,
        # about three runs each; 3 cells, five rounds of merges)
        cells = rng.integers(0, size, count)
        values = rng.normal(size=count) * 10.0
        values[rng.random(count) < 0.3] = 2.0  # repeated values
        values[rng.random(count) < 0.05] = -0.0
        counts = np.bincount(cells, minlength=size)
        found = cell_medians(cells, values, counts)
        if count:
            # bit for bit: the sign of a zero median too
            expected = lexsort_medians(cells, values, size)
            assert np.array_equal(found.view(np.int64), expected.view(np.int64))
        else:
            assert np.isnan(found).all()


def test_cell_medians_values():
    cells = np.array([2, 0, 2, 2, 0])
    values = np.array([5.0, 1.0, -1.0, 3.0, 4.0])
    found = cell_medians(cells, values, np.bincount(cells, minlength=4))
    assert np.array_equal(found, [2.5, np.nan, 3.0, np.nan], equal_nan=True)
