"""refine on every core (issue 47): the parts that ran on one core — the median filter's
rank sort, the shadow mask's dilation, the albedo's normalised-convolution arithmetic —
now run on all, with the same numbers to the bit."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy import ndimage

from demtool.refine.albedo import estimate_albedo
from demtool.refine.filters import gaussian_lowpass, masked_gaussian_lowpass, median_filter
from demtool.refine.shadows import dilate


@pytest.fixture
def two_threads():
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    yield numba.get_num_threads()
    numba.set_num_threads(before)


@pytest.mark.parametrize("shape", [(300, 257), (129, 64), (64, 700)])
def test_median_filter_in_strips_is_scipys(shape, two_threads):
    rng = np.random.default_rng(0)
    values = rng.normal(size=shape).astype(np.float32)
    values[::5] = np.round(values[::5], 1)  # ties across the strips' boundary rows
    for size in (3, 15):
        expected = ndimage.median_filter(values, size, mode="reflect")
        assert np.array_equal(median_filter(values, size), expected)
        numba.set_num_threads(1)
        assert np.array_equal(median_filter(values, size), expected)
        numba.set_num_threads(two_threads)


def test_dilation_is_scipys():
    rng = np.random.default_rng(1)
    for shape in [(1, 1), (1, 9), (9, 1), (50, 37)]:
        for fraction in (0.01, 0.3):
            mask = rng.random(shape) < fraction
            for iterations in (1, 2):
                assert np.array_equal(dilate(mask, iterations),
                                      ndimage.binary_dilation(mask, iterations=iterations))


def _masked_lowpass_numpy(array, weight, sigma, floor=1e-3):
    """The numpy formula the kernels replace (f(w·a) / f(w), the weighted mean where
    f(w) ≤ floor)."""
    w = np.asarray(weight, dtype=np.float32)
    values = np.where(w > 0, np.asarray(array, dtype=np.float32), np.float32(0.0))
    numerator = gaussian_lowpass(values * w, sigma)
    denominator = gaussian_lowpass(w, sigma)
    fallback = np.float32(float((values * w).sum()) / float(w.sum()))
    safe = denominator > floor
    return np.where(safe, numerator / np.where(safe, denominator, 1.0), fallback)


def test_albedo_arithmetic_is_numpys(two_threads):
    rng = np.random.default_rng(5)
    shape = (200, 230)
    image = (800 * rng.random(shape)).astype(np.float32)
    image[rng.random(shape) < 0.05] = np.nan
    modelled = rng.normal(0.5, 0.3, shape).astype(np.float32)
    modelled[rng.random(shape) < 0.01] = np.nan
    lit = rng.random(shape) < 0.7
    lit[:70] = False  # no weight within a few σ: the weighted mean
    weights = (rng.random(shape) * lit).astype(np.float32)
    x = rng.normal(size=shape).astype(np.float32)
    assert np.array_equal(masked_gaussian_lowpass(x, weights, 21.0),
                          _masked_lowpass_numpy(x, weights, 21.0))
    assert np.array_equal(masked_gaussian_lowpass(x, lit, 5.0, floor=0.3),
                          _masked_lowpass_numpy(x, lit, 5.0, floor=0.3))
    for weight in (None, lit):
        usable = np.isfinite(image) & np.isfinite(modelled) & (modelled > 0)
        w = usable.astype(np.float32) if weight is None else np.where(usable, weight, 0)
        smooth_image = _masked_lowpass_numpy(image, w, 21.0)
        smooth_model = _masked_lowpass_numpy(modelled, w, 21.0)
        floor = np.float32(1e-6 * float(np.max(smooth_model)))
        expected = smooth_image / np.maximum(smooth_model, floor)
        assert (expected > 0).all()
        assert np.array_equal(estimate_albedo(image, modelled, sigma=21.0, weight=weight),
                              expected)


def test_segment_residuals_on_every_core_are_the_serial_sums(two_threads):
    from demtool.refine.shadow_lengths import ShadowSegments, segment_residuals

    rng = np.random.default_rng(3)
    p, q = (rng.normal(size=(40, 50)).astype(np.float32) for _ in range(2))
    lengths = rng.integers(1, 9, 200)
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    n = int(starts[-1])
    segments = ShadowSegments(starts, rng.integers(0, 40, n), rng.integers(0, 50, n),
                              rng.normal(size=n).astype(np.float32),
                              rng.normal(size=n).astype(np.float32),
                              rng.normal(size=200).astype(np.float32))
    expected = np.empty(200)
    for s in range(200):
        total = 0.0
        for j in range(starts[s], starts[s + 1]):
            r, c = segments.rows[j], segments.cols[j]  # float32 terms, float64 sum
            total += float(segments.coef_p[j] * p[r, c] + segments.coef_q[j] * q[r, c])
        expected[s] = total - float(segments.target[s])
    assert np.array_equal(segment_residuals(p, q, segments), expected)


def test_row_kernels_on_two_threads_are_one_threads(two_threads):
    """The solver's kernels run in row parts (demtool.tiling.rows.on_row_parts): each
    part writes only its rows and the sums add the row sums in row order, so the
    outputs do not depend on the thread count, to the bit."""
    from demtool.refine import kernels
    from demtool.refine.shading import Illumination
    from demtool.refine.shadows import cast_shadows

    rng = np.random.default_rng(11)
    shape = (260, 97)  # two parts of 130 rows on two threads
    p, q, gx, gy, p0, q0, bp, bq, R, normalised = (
        rng.normal(0, 0.3, shape).astype(np.float32) for _ in range(10))
    weight = rng.random(shape).astype(np.float32)
    sun = np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74])
    dem = np.cumsum(rng.normal(size=shape), axis=1)

    def outputs():
        out = {}
        for code in (0, 1):
            arrays = [np.empty(shape, np.float32) for _ in range(3)]
            kernels.reflectance_partials(p, q, sun, np.array([0.0, 0.1, 0.995]), 0.7, code,
                                         *arrays)
            out[f"reflectance {code}"] = arrays
        arrays = [np.empty(shape, np.float32) for _ in range(5)]
        kernels.central_gradient(p, 0.8, arrays[0], arrays[1])
        kernels.slope_step(p, q, gx, gy, R, bp, bq, normalised, weight, p0, q0,
                           np.float32(0.3), np.float32(0.2), np.float32(0.0), arrays[2],
                           arrays[3])
        kernels.integrability_adjoint(p, q, gx, gy, 0.8, arrays[4])
        out["operators"] = arrays
        update = np.empty(shape, np.float32)
        kernels.height_update(p, q, gx, gy, weight, np.float32(0.4), update)
        coarse = np.empty((130, 48), np.float32)
        kernels.block_mean(np.ascontiguousarray(p[:, :96]), np.ascontiguousarray(q[:, :96]),
                           2, coarse)
        replicated = np.empty((260, 96), np.float32)
        kernels.block_replicate(coarse, 2, replicated)
        out["blocks"] = [update, coarse, replicated]
        out["sums"] = [kernels.energy_sums(p, q, gx, gy, p0, q0, bp, bq, R, normalised,
                                           weight),
                       np.float64(kernels.weighted_square_sum(weight, p, q))]
        out["shadows"] = [cast_shadows(dem, (1.0, 1.0), Illumination(sun, np.array(
            [0.0, 0.0, 1.0])))]
        return out

    both = outputs()
    numba.set_num_threads(1)
    one = outputs()
    numba.set_num_threads(two_threads)
    for name, arrays in one.items():
        for a, b in zip(arrays, both[name], strict=True):
            assert np.array_equal(a, b), name
    # the row sums in float64, in row order
    rows = np.empty(shape[0])
    kernels._weighted_square_sum_rows(weight, p, q, rows, 0, shape[0])
    assert one["sums"][1] == np.cumsum(rows)[-1]
    assert np.isclose(one["sums"][1], np.sum(weight * (p - q).astype(np.float64) ** 2),
                      rtol=1e-5)


def test_shadow_corrections_in_groups_without_common_pixels_are_the_serial_ones(two_threads):
    """correct_slope_step applies the crossings in order; cut where no pixel is shared
    (independent_splits), the groups run on two threads with the same numbers."""
    from demtool.refine.shadow_lengths import (
        ShadowSegments,
        correct_slope_step,
        independent_splits,
    )

    rng = np.random.default_rng(8)
    shape = (40, 50)
    lengths = rng.integers(2, 7, 120)
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    n = int(starts[-1])
    # segments in bands of 4 rows (20 per band) that share pixels inside a band only
    band = np.repeat(np.arange(120) // 20, lengths)
    rows = (4 * band + rng.integers(0, 4, n)).astype(np.int64)
    cols = rng.integers(0, 6, n).astype(np.int64)  # crowded: many shared pixels
    segments = ShadowSegments(starts, rows, cols, rng.normal(size=n).astype(np.float32),
                              rng.normal(size=n).astype(np.float32),
                              rng.normal(size=120).astype(np.float32))
    splits = independent_splits(segments, 2)
    assert len(splits) == 3 and splits[0] == 0 and splits[-1] == 120
    assert abs(splits[1] - 60) <= 20  # the band boundary nearest the middle
    pixels = [set(zip(rows[starts[a]:starts[b]], cols[starts[a]:starts[b]], strict=True))
              for a, b in zip(splits[:-1], splits[1:], strict=True)]
    assert not pixels[0] & pixels[1]
    p, q, Rp, Rq = (rng.normal(0, 0.3, shape).astype(np.float32) for _ in range(4))
    weight = rng.random(shape).astype(np.float32)
    step = rng.normal(0, 0.3, (2, *shape)).astype(np.float32)
    serial, grouped = step.copy(), step.copy()
    correct_slope_step(p, q, *serial, Rp, Rq, weight, 0.25, 0.5, segments)
    correct_slope_step(p, q, *grouped, Rp, Rq, weight, 0.25, 0.5, segments, splits)
    assert np.array_equal(serial, grouped)
    assert not np.array_equal(serial, step)
    # every pixel shared by neighbouring segments: no cut, one group
    chained = ShadowSegments(  # segment i covers columns i and i + 1 of row 0
        np.arange(0, 61, 2), np.zeros(60, np.int64),
        np.stack([np.arange(30), np.arange(1, 31)], axis=1).ravel(),
        np.ones(60, np.float32), np.ones(60, np.float32), np.zeros(30, np.float32))
    assert independent_splits(chained, 2).tolist() == [0, 30]


def test_solver_arrays_on_row_parts_are_one_threads(two_threads, monkeypatch):
    """The solver's numpy work between the kernels (images, DCT-domain terms, heights in
    pixel units and back, I/ρ, the lit weights, the dark and attached shadows, the
    Gaussian low-pass's product) runs on row parts in blocks: the refined DEM, albedo,
    shadows and energies of two threads in blocks of a few rows equal those of one
    thread in one block (the whole-array expressions), to the bit."""
    from demtool.refine import refine_heights, rowwork
    from demtool.refine.params import SfsParameters
    from demtool.refine.shading import make_illumination, render_dem, sun_from_angles

    rng = np.random.default_rng(4)
    truth = ndimage.gaussian_filter(rng.normal(size=(160, 90)), 3.0) * 30
    light = make_illumination(sun_from_angles(100.0, 20.0))  # low sun: shadows
    image = render_dem(truth, (1.0, 1.2), light) * (1 + 0.01 * rng.normal(size=truth.shape))
    image[3:9, 10:30] = np.nan
    coarse = ndimage.gaussian_filter(truth, 2.0)

    def refined():
        return refine_heights(image, coarse, spacing=(1.0, 1.2), illumination=light,
                              parameters=SfsParameters(iterations=6, update_every=2))

    monkeypatch.setattr(rowwork, "BLOCK_ELEMENTS", 700)  # blocks of 7 rows
    both = refined()
    numba.set_num_threads(1)
    monkeypatch.setattr(rowwork, "BLOCK_ELEMENTS", 1 << 30)  # one block
    one = refined()
    numba.set_num_threads(two_threads)
    assert 0.02 < one.shadow.mean() < 0.6
    for name in ("dem", "albedo", "shadow"):
        assert np.array_equal(getattr(one, name), getattr(both, name)), name
    assert one.history == both.history and one.energies == both.energies


def test_dark_pixels_on_row_parts_are_the_formula(two_threads, monkeypatch):
    from demtool.refine import rowwork
    from demtool.refine.shadows import dark_pixels

    monkeypatch.setattr(rowwork, "BLOCK_ELEMENTS", 500)
    rng = np.random.default_rng(9)
    values = rng.random((150, 61)).astype(np.float32)
    values[rng.random(values.shape) < 0.05] = np.nan
    valid = rng.random(values.shape) < 0.8
    for mask in (None, valid, True):
        usable = np.isfinite(values) if mask is None else mask & np.isfinite(values)
        assert np.array_equal(dark_pixels(values, 0.3, valid=mask, median=0.7),
                              usable & (values < 0.3 * 0.7))


def test_dct_domain_terms_in_blocks_are_the_formulas(two_threads, monkeypatch):
    from demtool.refine import filters, rowwork

    monkeypatch.setattr(rowwork, "BLOCK_ELEMENTS", 300)
    for shape in [(300, 257), (129, 64)]:
        rows, cols = filters.dct_frequencies(shape)
        expected = (np.exp(-0.5 * 5.25**2 * rows**2)
                    * np.exp(-0.5 * 5.25**2 * cols**2)).astype(np.float32)
        assert np.array_equal(filters.gaussian_transfer.__wrapped__(shape, 5.25), expected)
        expected = ((2.0 - 2.0 * np.cos(cols))
                    + 0.8**2 * (2.0 - 2.0 * np.cos(rows))).astype(np.float32)
        assert np.array_equal(filters.neumann_laplacian_eigenvalues(shape, 0.8), expected)
