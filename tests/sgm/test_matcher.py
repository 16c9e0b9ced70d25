"""Tests of the semi-global matching core (demtool.sgm) on small synthetic pairs."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.errors import InputError, ParameterError
from demtool.sgm import plan_strips, sgm
from demtool.sgm.aggregate import adapted_p2_table, aggregate_costs, callee_sources_digest
from demtool.sgm.cost import (
    census_pixel_cost,
    census_transform,
    gaussian_matrix,
    mi_cost_table,
    mutual_information_table,
    quantize,
    windowed_cost_volume,
)
from demtool.sgm.disparity import median_filter, remove_speckles, select_disparities
from demtool.sgm.matcher import P2_KAPPA, P2_KAPPA_NOISE, noise_sigma, p2_kappa
from demtool.sgm.strips import sweep_state_bytes
from tests.helpers.sgm import (
    error_rates,
    fractional_shift_pair,
    occlusion_pair,
    reference_aggregation,
    smooth_disparity_pair,
)

COSTS = ["hmi", "mi", "census", "ad"]


def nonoccluded(truth: np.ndarray) -> np.ndarray:
    """Left pixels whose match lies inside the right image (at least 1 px in)."""
    columns = np.arange(truth.shape[1])[None, :]
    return (columns - truth) >= 1


@pytest.fixture(scope="module")
def smooth_pair():
    return smooth_disparity_pair(offset=0.0)


@pytest.mark.parametrize("cost", COSTS)
def test_each_cost_recovers_a_smooth_disparity_field(smooth_pair, cost):
    left, right, truth = smooth_pair
    result = sgm(left, right, min_disparity=-12, num_disparities=24, cost=cost)
    rates = error_rates(result.disparity, truth, nonoccluded(truth))
    assert rates["bad2"] < 0.05, rates
    assert rates["mae"] < 0.2, rates
    assert rates["density"] > 0.9, rates
    assert result.disparity.dtype == np.float32 and result.disparity.shape == left.shape
    assert np.isfinite(result.disparity).any()
    # confidence is NaN exactly where the disparity is, and within 0..1 elsewhere
    assert np.array_equal(np.isnan(result.confidence), np.isnan(result.disparity))
    conf = result.confidence[np.isfinite(result.confidence)]
    assert conf.min() >= 0.0 and conf.max() <= 1.0
    assert result.timings["total"] > 0


def test_sixteen_paths_and_options(smooth_pair):
    left, right, truth = smooth_pair
    result = sgm(left, right, min_disparity=-12, num_disparities=24, cost="census", paths=16,
                 census_window="9x7", cost_window=3, adaptive_p2=True, median=1,
                 speckle_size=0)
    rates = error_rates(result.disparity, truth, nonoccluded(truth))
    assert rates["bad2"] < 0.05, rates
    assert result.parameters["paths"] == 16 and result.parameters["cost_window"] == 3


def test_left_right_check_marks_the_occlusion_invalid():
    left, right, truth, occluded = occlusion_pair()
    checked = sgm(left, right, min_disparity=0, num_disparities=20, cost="census", fill=False)
    unchecked = sgm(left, right, min_disparity=0, num_disparities=20, cost="census",
                    lr_check=False, fill=False)
    assert np.isnan(checked.disparity[occluded]).mean() > 0.7
    assert np.isnan(unchecked.disparity[occluded]).mean() < 0.1
    visible = nonoccluded(truth) & ~occluded
    rates = error_rates(checked.disparity, truth, visible)
    assert rates["bad2"] < 0.02 and rates["density"] > 0.95, rates


@pytest.mark.parametrize("cost", ["census", "hmi"])
def test_fill_gives_occlusions_the_background_with_zero_confidence(cost):
    left, right, truth, occluded = occlusion_pair()  # background 4, box 14
    rejected = np.isnan(sgm(left, right, min_disparity=0, num_disparities=20, cost=cost,
                            fill=False).disparity)
    filled = sgm(left, right, min_disparity=0, num_disparities=20, cost=cost)
    assert filled.parameters["fill"] is True
    hole = occluded & rejected
    assert hole.sum() > 0.5 * occluded.sum()
    # the occluded strip takes the background's 4 px, not the box's 14 px
    assert np.mean(np.abs(filled.disparity[hole] - 4.0) < 1.0) > 0.8
    assert np.all(filled.confidence[hole & np.isfinite(filled.disparity)] == 0.0)
    # everything the right view could match is filled; pixels kept are unchanged
    assert np.isfinite(filled.disparity[:, 20:]).all()
    kept = ~rejected
    assert np.mean(np.abs(filled.disparity[kept] - truth[kept]) < 1.0) > 0.97


def test_fill_invalid_background_and_median():
    from demtool.sgm.fill import fill_invalid

    disparity = np.full((5, 9), 10.0, dtype=np.float32)
    disparity[:, 5:] = 3.0  # a far surface right of a near one
    disparity[2, 4] = np.nan  # occluded: takes the background (second lowest)
    disparity[0:2, 1] = np.nan  # mismatches inside the near surface: the median
    occluded = np.zeros(disparity.shape, bool)
    occluded[2, 4] = True
    usable = np.ones(disparity.shape, bool)
    usable[4, 0] = False  # outside the left image: never filled
    disparity[4, 0] = np.nan
    out = fill_invalid(disparity, occluded, usable)
    assert out[2, 4] == 3.0
    assert np.all(out[0:2, 1] == 10.0)
    assert np.isnan(out[4, 0])
    assert np.isnan(disparity[2, 4])  # input not modified


@pytest.mark.parametrize("shift", [2.25, 2.5])
@pytest.mark.parametrize("cost", ["census", "hmi"])
def test_subpixel_accuracy_on_a_fractional_shift(cost, shift):
    left, right = fractional_shift_pair(shift)
    result = sgm(left, right, min_disparity=0, num_disparities=8, cost=cost)
    found = result.disparity[:, 8:]
    assert np.isfinite(found).mean() > 0.95
    assert abs(np.nanmean(found) - shift) < 0.1
    assert np.nanmean(np.abs(found - shift)) < 0.12
    integer = sgm(left, right, min_disparity=0, num_disparities=8, cost=cost, subpixel="none",
                  median=1)
    assert np.nanmean(np.abs(integer.disparity[:, 8:] - shift)) > 0.2


@pytest.mark.parametrize("cost", ["hmi", "mi"])
def test_mutual_information_is_robust_to_a_gain_change(cost):
    left, right, truth = smooth_disparity_pair(offset=0.0, gain=0.6, bias=300.0)
    squared = (right / 700.0) ** 2 * 1000.0  # and to a monotonic non-linear response
    for partner in (right, squared):
        result = sgm(left, partner, min_disparity=-12, num_disparities=24, cost=cost)
        rates = error_rates(result.disparity, truth, nonoccluded(truth))
        assert rates["bad2"] < 0.05 and rates["density"] > 0.9, rates
    # absolute difference is not: the same pair defeats it
    result = sgm(left, right, min_disparity=-12, num_disparities=24, cost="ad")
    assert error_rates(result.disparity, truth, nonoccluded(truth))["bad2"] > 0.5


def test_nan_pixels_never_match_and_come_out_nan(smooth_pair):
    left, right, truth = (a.copy() for a in smooth_pair)
    left[:, :10] = np.nan  # outside the warped left image
    left[40:50, 60:70] = np.nan
    right[20:40, 30:50] = np.nan
    result = sgm(left, right, min_disparity=-12, num_disparities=24, cost="hmi")
    disparity = result.disparity
    assert np.isnan(disparity[:, :10]).all() and np.isnan(disparity[40:50, 60:70]).all()
    rows, cols = np.nonzero(np.isfinite(disparity))
    matched = np.rint(cols - disparity[rows, cols]).astype(int)
    inside = (matched >= 0) & (matched < right.shape[1])
    assert inside.all()
    assert np.isfinite(right[rows, matched]).all()
    mask = nonoccluded(truth) & np.isfinite(left)
    assert error_rates(disparity, truth, mask)["bad2"] < 0.05


def test_strips_match_the_whole_image():
    left, right, truth = smooth_disparity_pair(height=200, width=96, offset=0.0)
    fixed = 2 * sweep_state_bytes(96, 24, 8, 5)  # the two sweeps' row buffers (census)
    assert len(plan_strips(200, 96, 24, workers=1, max_memory_mb=0.6, fixed_bytes=fixed)) > 2
    whole = sgm(left, right, min_disparity=-12, num_disparities=24, cost="census", workers=1)
    # strips one after the other, and two strips at once (0.6 MiB each)
    for workers, budget in ((1, 0.6), (4, 1.2)):
        strips = sgm(left, right, min_disparity=-12, num_disparities=24, cost="census",
                     workers=workers, max_memory_mb=budget)
        same = np.isclose(whole.disparity, strips.disparity, atol=0.05, equal_nan=True)
        assert same.mean() > 0.97
        rates = error_rates(strips.disparity, truth, nonoccluded(truth))
        assert rates["bad2"] < 0.05, rates


@pytest.mark.parametrize("cost", ["census", "hmi"])
@pytest.mark.parametrize("paths", [8, 16])
def test_two_sweep_threads_give_the_single_thread_result(smooth_pair, cost, paths):
    # the down and up sweeps run in two threads, each storing half the rows' partial sums
    # and finishing the other half: exactly the same sums, so exactly the same disparity
    left, right, _ = smooth_pair
    one = sgm(left, right, min_disparity=-12, num_disparities=24, cost=cost, paths=paths,
              workers=1)
    two = sgm(left, right, min_disparity=-12, num_disparities=24, cost=cost, paths=paths,
              workers=2)
    assert np.array_equal(one.disparity, two.disparity, equal_nan=True)
    assert np.array_equal(one.confidence, two.confidence, equal_nan=True)


def test_plan_strips_bounds_memory():
    # the 2048² × 128 aggregated cost (1 GiB of uint16) fits the default budget: one strip
    assert plan_strips(2048, 2048, 128, workers=1, max_memory_mb=1400) == [(0, 2048)]
    fixed = 20 * 2**20
    strips = plan_strips(2048, 2048, 128, workers=2, max_memory_mb=1400, fixed_bytes=fixed)
    assert strips[0][0] == 0 and strips[-1][1] == 2048 and len(strips) % 2 == 0
    for start, stop in strips:
        rows = stop - start + 2 * 32
        assert 2 * (rows * 2048 * 128 * 2 + fixed) <= 1400 * 2**20
    strips = plan_strips(2048, 2048, 128, workers=1, max_memory_mb=500)
    assert len(strips) == 3 and all(b - a + 64 <= 500 * 2**19 // (2048 * 128) for a, b in strips)
    assert plan_strips(100, 120, 16, workers=4, max_memory_mb=1400) == [(0, 100)]
    with pytest.raises(ParameterError, match="max-memory-mb"):
        plan_strips(2048, 2048, 128, workers=2, max_memory_mb=10)


def test_bad_inputs_raise_clear_errors(smooth_pair):
    left, right, _ = smooth_pair
    with pytest.raises(InputError, match="differ in size"):
        sgm(left, right[:, :-1], min_disparity=0, num_disparities=8)
    with pytest.raises(InputError, match="right image contains no valid"):
        sgm(left, np.full_like(right, np.nan), min_disparity=0, num_disparities=8)
    with pytest.raises(ParameterError, match="wider than the image"):
        sgm(left, right, min_disparity=0, num_disparities=200)
    with pytest.raises(ParameterError, match="wider than the image"):
        sgm(left, right, min_disparity=-300, num_disparities=10)
    with pytest.raises(ParameterError, match="unknown cost"):
        sgm(left, right, min_disparity=0, num_disparities=8, cost="ncc")
    with pytest.raises(ParameterError, match="P1"):
        sgm(left, right, min_disparity=0, num_disparities=8, p1=100, p2=10)
    with pytest.raises(ParameterError, match="overflow"):
        sgm(left, right, min_disparity=0, num_disparities=8, cost="census", paths=16,
            cost_window=15, p2=2000)
    with pytest.raises(ParameterError, match="odd"):
        sgm(left, right, min_disparity=0, num_disparities=8, cost_window=4)


def test_census_transform_bits():
    image = np.arange(25, dtype=np.float32).reshape(5, 5)
    codes = census_transform(image, (3, 3))
    # at the centre, the four neighbours before it in raster order are darker
    assert codes[2, 2] == 0b11110000
    assert census_transform(image, (5, 5)).dtype == np.uint32  # 24 bits
    assert census_transform(image, (7, 9)).dtype == np.uint64  # 62 bits
    with pytest.raises(ValueError):
        census_transform(image, (4, 5))


def test_mutual_information_favours_corresponding_levels():
    rng = np.random.default_rng(0)
    left = rng.integers(0, 32, size=(64, 64)).astype(np.uint8)
    right = (31 - left).astype(np.uint8)  # inverted contrast: MI does not mind
    valid = np.ones(left.shape, dtype=bool)
    mi, pairs = mutual_information_table(left, right, valid, valid,
                                         np.zeros(left.shape, np.float32), levels=32)
    assert pairs == left.size
    table = mi_cost_table(mi)
    levels = np.arange(32)
    assert (table[levels, 31 - levels] <= table.min(axis=1) + 1).all()
    assert table[levels, levels].mean() > table[levels, 31 - levels].mean() + 10


@pytest.mark.parametrize("paths", [8, 16])
@pytest.mark.parametrize("kappa", [0, 8])
def test_aggregation_follows_the_recursion(paths, kappa):
    rng = np.random.default_rng(2)
    cost = rng.integers(0, 50, size=(6, 9, 6)).astype(np.uint16)
    guide = rng.integers(0, 40, size=(6, 9)).astype(np.uint8)
    total = aggregate_costs(cost, p1=3, p2=20, paths=paths, guide=guide, p2_kappa=kappa)
    expected = reference_aggregation(cost, guide, paths, kappa, 3, 20)
    assert np.array_equal(total, expected)


def test_selection_takes_the_right_disparity_from_the_same_cost():
    # one row, disparities 0..3: the left pixel 5 prefers d=2, its right pixel 3 prefers d=0
    total = np.full((1, 8, 4), 100, dtype=np.uint16)
    total[0, :, 2] = 10
    total[0, 3, 0] = 1  # right pixel 3 = left pixel 3 at d=0: better than left 5 at d=2
    valid = np.ones((1, 8), dtype=bool)
    disparity, confidence = select_disparities(total, min_disparity=0, left_valid=valid,
                                               right_valid=valid, lr_threshold=1.0)
    assert np.isnan(disparity[0, 5])  # inconsistent with the right image
    assert disparity[0, 4] == pytest.approx(2.0)
    assert confidence[0, 4] == pytest.approx(0.9)
    unchecked, _ = select_disparities(total, min_disparity=0, left_valid=valid,
                                      right_valid=valid, lr_threshold=None)
    assert unchecked[0, 5] == pytest.approx(2.0)
    assert np.isnan(unchecked[0, 1])  # x − d < 0: no right pixel


def test_speckles_and_median():
    disparity = np.full((20, 20), 5.0, dtype=np.float32)
    disparity[3:5, 3:5] = 15.0  # a 4-pixel speckle
    disparity[10, 10] = np.nan
    cleaned = remove_speckles(disparity, max_size=10, max_difference=1.0)
    assert np.isnan(cleaned[3:5, 3:5]).all() and np.isnan(cleaned[10, 10])
    assert np.isfinite(cleaned).sum() == 400 - 5
    noisy = np.full((9, 9), 2.0, dtype=np.float32)
    noisy[4, 4] = 9.0
    noisy[0, 0] = np.nan
    smoothed = median_filter(noisy, 3)
    assert smoothed[4, 4] == 2.0 and np.isnan(smoothed[0, 0])


def test_census_transform_matches_a_direct_count():
    rng = np.random.default_rng(4)
    image = rng.normal(size=(11, 14)).astype(np.float32)
    codes = census_transform(image, (3, 5))  # 3 rows, 5 columns
    padded = np.pad(image, ((1,), (2,)), mode="edge")
    for y, x in [(0, 0), (5, 7), (10, 13), (3, 1)]:
        bits = [padded[y + dy, x + dx] < image[y, x]
                for dy in range(3) for dx in range(5) if (dy, dx) != (1, 2)]
        assert codes[y, x] == int("".join("1" if b else "0" for b in bits), 2)


def test_windowed_cost_rows_match_a_direct_window_sum():
    rng = np.random.default_rng(6)
    left = rng.normal(size=(9, 20)).astype(np.float32)
    right = rng.normal(size=(9, 20)).astype(np.float32)
    valid = np.ones(left.shape, dtype=bool)
    right_valid = valid.copy()
    right_valid[4, 6] = False
    pixel_cost = census_pixel_cost(left, right, (3, 3))
    volume = windowed_cost_volume(pixel_cost, valid, right_valid, min_disparity=-2,
                                  num_disparities=5, window=3, rows=(2, 8),
                                  unmatched_fraction=0.5)
    # pixel costs by brute force: Hamming distance, 4 (half of 8 bits) outside or on NaN
    pixel = np.full((9, 20, 5), 4, dtype=np.int64)
    for y in range(9):
        for x in range(20):
            for k, d in enumerate(range(-2, 3)):
                xr = x - d
                if 0 <= xr < 20 and right_valid[y, xr]:
                    code = int(pixel_cost.left[y, x]) ^ int(pixel_cost.right[y, xr])
                    pixel[y, x, k] = bin(code).count("1")
    padded = np.pad(pixel, ((1,), (1,), (0,)), mode="edge")
    expected = sum(padded[1 + dy:10 + dy, 1 + dx:21 + dx] for dy in (-1, 0, 1)
                   for dx in (-1, 0, 1))
    assert np.array_equal(volume, expected[2:8])


@pytest.mark.parametrize("mode", ["constant", "nearest"])
def test_gaussian_matrix_is_scipys_gaussian_filter(mode):
    from scipy import ndimage

    values = np.random.default_rng(8).random((32, 32))
    matrix = gaussian_matrix(32, 1.3, mode)
    expected = ndimage.gaussian_filter(values, 1.3, mode=mode)
    assert np.allclose(matrix @ values @ matrix.T, expected, atol=1e-12)


def test_median_of_nine_network_is_the_median():
    from numpy.lib.stride_tricks import sliding_window_view

    rng = np.random.default_rng(9)
    disparity = np.round(rng.normal(size=(30, 31)) * 3).astype(np.float32)  # with ties
    disparity[7, 9] = np.nan
    filtered = median_filter(disparity, 3)
    windows = sliding_window_view(disparity, (3, 3))
    expected = np.nanmedian(windows.reshape(28, 29, 9), axis=2)
    inner = filtered[1:-1, 1:-1]
    assert np.isnan(inner[6, 8]) and np.isnan(filtered[7, 9])
    keep = np.isfinite(disparity[1:-1, 1:-1])
    assert np.allclose(inner[keep], expected[keep])


def test_quantize_stretches_and_fills_nan():
    image = np.linspace(0.0, 1000.0, 200, dtype=np.float32).reshape(10, 20)
    image[0, 0] = np.nan
    valid = np.isfinite(image)
    levels = quantize(image, valid, 64, value_range=(100.0, 900.0))
    assert levels.dtype == np.uint8 and levels.min() == 0 and levels.max() == 63
    expected = np.clip(np.rint((image - 100.0) * 63 / 800.0), 0, 63)
    assert np.array_equal(levels[valid], expected[valid])
    assert levels[0, 0] == levels[0, 1]  # nearest valid neighbour


def test_adapted_p2_table():
    table = adapted_p2_table(50, 700, 8)
    assert table.shape == (256,) and (table[:9] == 700).all()  # steps up to κ keep P2
    assert table[16] == 350 and table[28] == 200  # P2·κ/|ΔI|
    assert table[255] == 50  # never below P1
    assert (np.diff(table) <= 0).all()
    assert (adapted_p2_table(50, 700, 0) == 700).all()  # κ = 0: constant P2


def test_sweep_kernel_cache_key_covers_the_kernels_it_inlines():
    # numba's cache keys a function on its own file and closure only: sweep_rows and the
    # path kernel close over a digest of cost.py, disparity.py and simd.py, so editing
    # them recompiles both
    import hashlib
    from pathlib import Path

    from demtool.sgm import aggregate

    folder = Path(aggregate.__file__).parent
    expected = hashlib.sha256(b"".join((folder / name).read_bytes() for name in
                                       ("cost.py", "disparity.py", "simd.py"))).hexdigest()
    assert callee_sources_digest() == expected
    for kernel in (aggregate.sweep_rows, aggregate._four_paths, aggregate._paths_rows):
        assert expected in [c.cell_contents for c in kernel.py_func.__closure__]


def test_fill_invalid_matches_a_brute_force_search():
    from demtool.sgm.fill import fill_invalid

    rng = np.random.default_rng(7)
    disparity = rng.uniform(0, 20, (23, 31)).astype(np.float32)
    disparity[rng.random(disparity.shape) < 0.6] = np.nan
    occluded = rng.random(disparity.shape) < 0.5
    usable = rng.random(disparity.shape) < 0.9
    out = fill_invalid(disparity, occluded, usable)
    height, width = disparity.shape
    for y in range(height):
        for x in range(width):
            if np.isfinite(disparity[y, x]) or not usable[y, x]:
                assert out[y, x] == disparity[y, x] or np.isnan(out[y, x])
                continue
            found = []
            for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
                yy, xx = y + dy, x + dx
                while 0 <= yy < height and 0 <= xx < width and usable[yy, xx]:
                    if np.isfinite(disparity[yy, xx]):
                        found.append(disparity[yy, xx])
                        break
                    yy, xx = yy + dy, xx + dx
            found.sort()
            if not found:
                assert np.isnan(out[y, x])
            elif occluded[y, x]:
                assert out[y, x] == (found[1] if len(found) > 2 else found[0])
            else:
                assert out[y, x] == pytest.approx(float(np.median(found)))



@pytest.mark.parametrize("sigma", [0.5, 3.0, 10.0])
def test_noise_sigma_of_white_noise_on_a_smooth_image(sigma):
    rng = np.random.default_rng(1)
    rows, cols = np.mgrid[0:200, 0:240]
    smooth = 100 + 0.3 * cols + 20 * np.sin(rows / 30.0)  # planar-ish signal: cancelled
    image = smooth + rng.normal(0, sigma, smooth.shape)
    valid = np.ones(image.shape, bool)
    assert noise_sigma(image, valid) == pytest.approx(sigma, rel=0.08)


def test_noise_sigma_ignores_edges_and_invalid_pixels():
    rng = np.random.default_rng(2)
    image = np.where(np.arange(200)[None, :] % 40 < 20, 50.0, 200.0) * np.ones((150, 1))
    image = image + rng.normal(0, 2.0, image.shape)
    valid = np.ones(image.shape, bool)
    valid[:, :30] = False
    image[:, :30] = 1e6  # garbage where invalid
    assert noise_sigma(image, valid) == pytest.approx(2.0, rel=0.1)
    assert noise_sigma(image[:2], valid[:2]) == 0.0


def test_p2_kappa_grows_with_the_noise_only_above_the_floor():
    rng = np.random.default_rng(3)
    valid = np.ones((100, 100), bool)
    quiet = np.full((100, 100), 128.0) + rng.normal(0, 0.5, (100, 100))
    noisy = np.full((100, 100), 128.0) + rng.normal(0, 8.0, (100, 100))
    assert p2_kappa(quiet, valid) == P2_KAPPA
    assert p2_kappa(noisy, valid) == pytest.approx(P2_KAPPA_NOISE * 8.0, abs=2.5)
