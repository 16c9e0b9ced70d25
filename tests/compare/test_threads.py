"""compare on two threads (demtool.compare.threads) and the shortcuts that keep its numbers:
the side thread within the caller's limits, the same sums, shades, spectra and figures."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from demtool.compare import threads


def test_the_side_thread_keeps_the_callers_thread_limits():
    import numba

    from demtool.tiling.tasks import numba_threads_at_most, threads_limited, usable_threads

    seen = {}

    def inside():
        seen["usable"] = usable_threads()
        seen["numba"] = numba.get_num_threads()
        seen["thread"] = threading.get_ident()

    with threads_limited(1), numba_threads_at_most(1):
        with threads.Side(True) as side:
            side.later(inside).result()
    assert seen["thread"] != threading.get_ident()  # it ran on the side thread
    assert seen == {"usable": 1, "numba": 1, "thread": seen["thread"]}
    with threads_limited(1):
        assert not threads.threaded(10 * threads.THREADED_CELLS)  # one thread: no side


def test_both_raises_the_first_error_as_in_turn():
    def first():
        raise ValueError("first")

    def second():
        raise KeyError("second")

    for on in (False, True):
        with pytest.raises(ValueError, match="first"):
            threads.both(first, second, on=on)
    assert threads.both(lambda: 1, lambda: 2, on=True) == (1, 2)


@pytest.mark.parametrize("shape", [(2, 9), (3, 3), (7, 10), (101, 37)])
def test_the_shown_cells_shade_is_the_whole_grids(shape):
    from demtool.compare.plots import hillshade

    rng = np.random.default_rng(shape[0])
    dem = rng.normal(size=shape).cumsum(0).cumsum(1)
    dem[rng.random(shape) < 0.02] = np.nan
    for stride in (1, 2, 3, 7):
        np.testing.assert_array_equal(hillshade(dem, (0.7, 1.3), stride=stride),
                                      hillshade(dem, (0.7, 1.3))[::stride, ::stride])


def _lstsq_detrended(values, valid):
    """The least-squares plane removed by numpy's SVD solver (the former detrending)."""
    rows, cols = np.nonzero(valid)
    design = np.column_stack([np.ones(rows.size), rows, cols])
    coef = np.linalg.lstsq(design, values[valid], rcond=None)[0]
    r, c = np.indices(values.shape)
    return np.where(valid, values - (coef[0] + coef[1] * r + coef[2] * c), 0.0)


def test_the_spectrum_on_two_threads_and_its_plane():
    from demtool.imaging.spectral import _detrend, coherence_spectrum

    rng = np.random.default_rng(5)
    n = 200
    surface = rng.normal(size=(n, n)).cumsum(0).cumsum(1) * 0.01 + 1500.0
    surface += 0.3 * np.arange(n)[:, None] - 0.2 * np.arange(n)[None, :]
    other = surface + rng.normal(scale=0.1, size=surface.shape)
    other[60:90, 20:50] = np.nan
    valid = np.isfinite(other)
    # the plane: least squares to float rounding (heights ~1500 m: ~1e-12 m)
    np.testing.assert_allclose(_detrend(other, valid), _lstsq_detrended(other, valid),
                               rtol=0, atol=1e-9)
    for policy in ("fill", "crop"):
        one = coherence_spectrum(surface, other, spacing=0.5, nan_policy=policy)
        two = coherence_spectrum(surface, other, spacing=0.5, nan_policy=policy, threads=2)
        for name in one._fields:
            np.testing.assert_array_equal(getattr(two, name), getattr(one, name))


@pytest.mark.slow  # two sets of six figures: ~4 CPU s
def test_figures_on_two_threads_are_the_same_bytes(monkeypatch):
    from demtool.compare import compare_dems
    from demtool.compare.plots import default_profiles
    from demtool.compare.report import make_figures

    rng = np.random.default_rng(2)
    reference = rng.normal(size=(48, 60)).cumsum(0).cumsum(1) * 0.1
    dem = reference + rng.normal(scale=0.05, size=reference.shape) + 0.4
    dem[5:9, 10:14] = np.nan
    comparison = compare_dems(dem, reference, spacing=1.5)
    args = ([("dem", comparison)], reference, default_profiles(reference.shape), (1.5, 1.5),
            "dem")
    monkeypatch.setattr(threads, "THREADED_CELLS", 1 << 40)
    alone = make_figures(*args)
    monkeypatch.setattr(threads, "THREADED_CELLS", 64)
    together = make_figures(*args)
    assert list(together) == list(alone) and len(alone) == 6
    for name, png in alone.items():
        assert together[name] == png, name


def test_the_row_sums_are_numbas_in_row_order():
    from numba import njit

    from demtool.compare.coreg import _gradient_sums

    @njit
    def numba_sum(partial):  # the former kernel's sum of its rows' sums
        return partial.sum(axis=0)

    rng = np.random.default_rng(3)
    partial = rng.normal(size=(999, 10)) * 10.0 ** rng.integers(-8, 8, size=(999, 10))
    np.testing.assert_array_equal(partial.sum(axis=0), numba_sum(partial))
    grad_x, grad_y, dh = (rng.normal(size=(33, 41)) for _ in range(3))
    usable = rng.random((33, 41)) > 0.1
    args = (grad_x, grad_y, dh, usable, np.array([0.1, -0.2, 0.3]), 0.01, 2.0)
    np.testing.assert_array_equal(_gradient_sums(*args, threads=True),
                                  _gradient_sums(*args, threads=False))


def test_the_bootstrap_on_two_threads_gives_the_same_sigmas():
    from demtool.compare.coreg import _block_ids, _bootstrap_sigma

    rng = np.random.default_rng(4)
    shape = (60, 50)
    blocks = _block_ids(shape).ravel()
    design = np.column_stack([rng.normal(size=blocks.size), rng.normal(size=blocks.size),
                              -np.ones(blocks.size)])
    target = design @ np.array([0.3, -0.2, 0.1]) + rng.normal(scale=0.05, size=blocks.size)
    np.testing.assert_array_equal(_bootstrap_sigma(design, target, blocks, threads=True),
                                  _bootstrap_sigma(design, target, blocks, threads=False))
