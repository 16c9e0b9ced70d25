"""Nuth & Kääb's normal-equation sums (compare.coreg._gradient_sums) against their
definition: per row in column order, then the rows added in row order (as the kernel's
former ``partial.sum(axis=0)``), to the bit; and the fit's erosion against scipy's."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.compare.coreg import _gradient_sums


def _by_definition(grad_x, grad_y, dh, usable, params, centre, halfwidth):
    rows, cols = dh.shape
    partial = np.zeros((rows, 10))
    for r in range(rows):
        acc = [0.0] * 10
        for c in range(cols):
            d, gx, gy = dh[r, c], grad_x[r, c], grad_y[r, c]
            if not usable[r, c] or not (np.isfinite(d) and np.isfinite(gx)
                                        and np.isfinite(gy)):
                continue
            if halfwidth > 0.0:
                model = params[0] * gx + params[1] * gy - params[2]
                if abs(d - model - centre) > halfwidth:
                    continue
            terms = (gx * gx, gx * gy, gx, gy * gy, gy, 1.0, gx * d, gy * d, d, d * d)
            for k, term in enumerate(terms):  # -gx, -gy and -d are subtracted
                acc[k] = acc[k] - term if k in (2, 4, 8) else acc[k] + term
        partial[r] = acc
    total = np.zeros(10)
    for r in range(rows):
        total += partial[r]
    return total


@pytest.mark.parametrize("halfwidth", [0.0, 0.8])
def test_gradient_sums_are_the_row_ordered_sums_to_the_bit(halfwidth):
    rng = np.random.default_rng(2)
    grad_x, grad_y, dh = (rng.normal(size=(23, 17)) for _ in range(3))
    dh[rng.random(dh.shape) < 0.1] = np.nan
    usable = rng.random(dh.shape) > 0.15
    params = np.array([0.3, -0.2, 0.1])
    got = _gradient_sums(grad_x, grad_y, dh, usable, params, 0.05, halfwidth)
    expected = _by_definition(grad_x, grad_y, dh, usable, params, 0.05, halfwidth)
    assert np.array_equal(got.view(np.uint64), expected.view(np.uint64))
    assert 0 < got[5] < dh.size  # some pixels used, some left out


def test_the_fit_erosion_is_scipys_binary_erosion():
    from scipy.ndimage import binary_erosion

    from demtool.compare.coreg import _eroded

    rng = np.random.default_rng(4)
    for shape in [(1, 1), (1, 7), (6, 1), (3, 3), (40, 31)]:
        mask = rng.random(shape) < 0.8
        for iterations in (1, 2, 3):
            assert np.array_equal(_eroded(mask, iterations),
                                  binary_erosion(mask, iterations=iterations))
    assert np.array_equal(_eroded(np.ones((9, 9), bool), 2),
                          binary_erosion(np.ones((9, 9), bool), iterations=2))
