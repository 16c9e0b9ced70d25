"""The comparison grid's row kernels (separable shifts, bilinear sampling) on row parts:
the same bits split over threads as on one, and the values of their formulas."""

from __future__ import annotations

import numpy as np

from demtool.compare import grids, shifts
from tests.helpers.row_parts import whole_and_split


def _surface(shape, seed=3):
    rng = np.random.default_rng(seed)
    values = rng.normal(size=shape).cumsum(0).cumsum(1) / 10.0
    holes = (rng.integers(0, shape[0], 6), rng.integers(0, shape[1], 6))
    values[holes] = np.nan  # a hole spreads to the outputs whose taps reach it
    return values


def _gaussian_shift_formula(values, dx, dy, sigma):
    """``out[y, x] = Σ_ij g(y − dy − i) g(x − dx − j) values[i, j]`` written with numpy:
    the taps of each axis around ``floor(−shift)``, NaN where a tap of non-zero weight is
    NaN or outside the grid."""
    radius = max(2, int(np.ceil(4.5 * sigma)))
    out = np.asarray(values, dtype=np.float64)
    for axis, shift in ((1, dx), (0, dy)):
        base = int(np.floor(-shift))
        weights = shifts._gaussian_taps(-shift - base, sigma, radius)
        taps = np.arange(-radius, radius + 2) + base
        moved = np.moveaxis(out, axis, 0)
        total = np.zeros(moved.shape)
        for tap, weight in zip(taps, weights, strict=True):
            if weight == 0.0:
                continue
            index = np.arange(moved.shape[0]) + tap
            inside = (index >= 0) & (index < moved.shape[0])
            term = np.full(moved.shape, np.nan)
            term[inside] = weight * moved[index[inside]]
            total = total + term
        out = np.moveaxis(total, 0, axis)
    return out


def test_gaussian_shift_on_row_parts_is_one_threads_and_the_formula(monkeypatch):
    values = _surface((200, 70))
    whole, split, seen = whole_and_split(
        monkeypatch, lambda: shifts.gaussian_shift(values, 0.37, -1.45, 1.3))
    assert any(len(parts) == 3 for parts in seen)  # split: 200 rows in 3 parts
    assert whole.tobytes() == split.tobytes()
    expected = _gaussian_shift_formula(values, 0.37, -1.45, 1.3)
    assert np.array_equal(np.isnan(whole), np.isnan(expected))
    assert np.nanmax(np.abs(whole - expected)) < 1e-12
    assert np.isfinite(whole).mean() > 0.5  # not all holes: the values were compared


def test_gaussian_shift_into_given_buffers_is_the_same_shift():
    """Nuth & Kääb shifts one DEM again and again into the same buffers: filled buffers
    hold the numbers of new arrays, whatever they held before; a buffer of another
    shape, type or layout is refused, not reshaped."""
    import pytest

    values = _surface((60, 45))
    expected = shifts.gaussian_shift(values, 0.37, -1.45, 1.3)
    out, scratch = np.full(values.shape, 7.0), np.full(values.shape, np.nan)
    for dx in (0.37, -2.2, 0.37):  # the buffers reused, from another shift's numbers
        got = shifts.gaussian_shift(values, dx, -1.45, 1.3, out=out, scratch=scratch)
    assert got is out
    assert got.tobytes() == expected.tobytes()
    for bad in (np.empty((60, 44)), np.empty(values.shape, np.float32),
                np.empty((45, 60)).T):
        with pytest.raises(ValueError, match="buffer"):
            shifts.gaussian_shift(values, 0.37, -1.45, 1.3, out=bad)


def test_sample_bilinear_on_row_parts_is_one_threads_and_the_formula(monkeypatch):
    values = _surface((200, 250), seed=5)
    rng = np.random.default_rng(6)
    rows = rng.uniform(-1.0, 200.5, size=(200, 250))  # some outside the grid: NaN
    cols = rng.uniform(-1.0, 250.5, size=(200, 250))
    rows[0, :5] = np.nan
    whole, split, seen = whole_and_split(
        monkeypatch, lambda: grids.sample_bilinear(values, rows, cols))
    assert any(len(parts) == 3 for parts in seen)  # 50 000 samples in 3 parts
    assert whole.tobytes() == split.tobytes()
    r0, c0 = np.floor(rows), np.floor(cols)
    fy, fx = rows - r0, cols - c0
    inside = (r0 >= 0) & (r0 + 1 < 200) & (c0 >= 0) & (c0 + 1 < 250)
    r, c = np.where(inside, r0, 0).astype(int), np.where(inside, c0, 0).astype(int)
    expected = ((1 - fy) * (1 - fx) * values[r, c] + (1 - fy) * fx * values[r, c + 1]
                + fy * (1 - fx) * values[r + 1, c] + fy * fx * values[r + 1, c + 1])
    expected[~inside] = np.nan
    both = np.isfinite(whole) & np.isfinite(expected)
    assert both.mean() > 0.9
    assert np.max(np.abs(whole[both] - expected[both])) < 1e-12
    assert np.all(np.isnan(whole[~inside]))
    assert np.all(np.isnan(whole[0, :5]))


def _quadratic(rows, cols):
    return 0.02 * rows**2 - 0.015 * rows * cols + 0.01 * cols**2 + 0.3 * rows - 0.2 * cols + 5.0


def test_cubic_sampling_and_shift_on_row_parts_are_one_threads_and_exact_on_quadratics(
        monkeypatch):
    """Keys' cubic convolution (a = −0.5) reproduces quadratics exactly (Keys 1981, §III):
    samples and shifts of one inside the grid are the polynomial's values."""
    rows, cols = np.indices((200, 250), dtype=np.float64)
    values = _quadratic(rows, cols)
    values[100, 100] = np.nan  # the 4 × 4 taps around it give NaN
    rng = np.random.default_rng(7)
    at_rows = rng.uniform(2.0, 197.0, size=(200, 250))
    at_cols = rng.uniform(2.0, 247.0, size=(200, 250))
    whole, split, seen = whole_and_split(
        monkeypatch, lambda: (grids.sample_cubic(values, at_rows, at_cols),
                              grids.shift_dem(values, 0.35, -1.25, 2.0, method="cubic")))
    assert any(len(parts) == 3 for parts in seen)
    for one, several in zip(whole, split, strict=True):
        assert one.tobytes() == several.tobytes()
    sampled, shifted = whole
    near_hole = (np.abs(at_rows - 100) < 2) & (np.abs(at_cols - 100) < 2)
    assert np.all(np.isnan(sampled[near_hole]))
    good = ~near_hole
    assert np.max(np.abs(sampled[good] - _quadratic(at_rows, at_cols)[good])) < 1e-9
    expected = _quadratic(rows + 1.25, cols - 0.35) + 2.0  # out[y, x] = dem[y − dy, x − dx] + dz
    inside = np.isfinite(shifted)
    assert inside.mean() > 0.9 and not inside[100, 100]
    assert np.max(np.abs(shifted[inside] - expected[inside])) < 1e-9
