"""The post-processing kernels run over two halves of the rows in two threads
(:func:`demtool.sgm.disparity.in_halves`): the result must be the one thread's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.sgm import disparity, edges
from demtool.sgm.disparity import in_halves, median_filter, remove_speckles
from demtool.sgm.edges import snap_edges
from demtool.sgm.fill import fill_classified, fill_invalid
from demtool.sgm.noise import noise_sigma


def _scene(seed: int = 3, shape: tuple[int, int] = (131, 97)):
    """A stepped disparity map with noise and NaN holes, its image and masks."""
    rng = np.random.default_rng(seed)
    height, width = shape
    yy, xx = np.mgrid[:height, :width]
    truth = np.where((xx - 40) ** 2 + (yy - 60) ** 2 < 30 ** 2, 25.0, 10.0)
    truth += np.where(xx > 70, 6.0, 0.0)
    image = (80.0 + 60.0 * (truth > 20) + 30.0 * (xx > 70)
             + rng.normal(0.0, 3.0, shape)).astype(np.float32)
    fattened = np.where((xx - 40) ** 2 + (yy - 60) ** 2 < 33 ** 2, 25.0, truth)
    measured = (fattened + rng.normal(0.0, 0.3, shape)).astype(np.float32)
    holes = rng.random(shape) < 0.08
    holes[50:58, 5:20] = True  # a larger invalid region
    measured[holes] = np.nan
    occluded = holes & (xx < 40)
    usable = np.ones(shape, dtype=bool)
    usable[:, :2] = False
    return measured, image, occluded, usable


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if a.dtype.kind != "f":
        return a.dtype == b.dtype and np.array_equal(a, b)
    keep = ~np.isnan(a)
    return bool(np.array_equal(np.isnan(a), np.isnan(b))
                and np.array_equal(a[keep].view(np.uint8), b[keep].view(np.uint8)))


def _run_all(measured, image, occluded, usable):
    snapped, moved = snap_edges(measured, image, 3, occluded, min_step=8.0)
    filled, classes = fill_classified(snapped, occluded & ~np.isfinite(snapped), usable)
    return [median_filter(measured, 3), median_filter(measured, 5),
            fill_invalid(measured, occluded, usable), snapped, moved, filled, classes,
            remove_speckles(measured, max_size=20, max_difference=1.0)]


def test_every_row_is_visited_once_in_order_within_its_half():
    seen: list[tuple[int, int]] = []
    in_halves(lambda start, stop: seen.append((start, stop)), 101, min_split=2)
    assert sorted(seen) in ([(0, 50), (50, 101)], [(0, 101)])  # one core: one call
    seen.clear()
    in_halves(lambda start, stop: seen.append((start, stop)), 5, min_split=64)
    assert seen == [(0, 5)]


def test_split_rows_give_the_one_thread_result_bit_for_bit(monkeypatch):
    scene = _scene()
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", 10 ** 9)
    single = _run_all(*scene)
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", 2)
    split = _run_all(*scene)
    assert len(single) == len(split)
    for one, two in zip(single, split, strict=True):
        assert _same(one, two)
    assert np.isfinite(single[5]).sum() > np.isfinite(scene[0]).sum()  # the fill filled
    assert single[4].any()  # and snapping moved pixels


@pytest.mark.parametrize("split", [2, 10 ** 9])
def test_smoothing_across_the_columns_is_the_transposed_smoothing(monkeypatch, split):
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", split)
    image = np.random.default_rng(1).integers(0, 256, size=(67, 45)).astype(np.uint8)
    smooth, steps = edges._smooth_and_steps(image, along=0)
    smooth_t, steps_t = edges._smooth_and_steps(np.ascontiguousarray(image.T), along=1)
    assert _same(smooth, np.ascontiguousarray(smooth_t.T))
    assert _same(steps, np.ascontiguousarray(steps_t.T))
    # along the rows: numpy's [1 2 1] in float32 and |diff| (the formula of issue 26)
    padded = np.pad(image.T.astype(np.float32), ((1, 1), (0, 0)), mode="edge")
    expected = 0.25 * padded[:-2] + 0.5 * padded[1:-1] + 0.25 * padded[2:]
    assert _same(smooth_t, expected)
    assert _same(steps_t[:, :-1], np.abs(np.diff(smooth_t, axis=1)))
    assert not steps_t[:, -1].any()


def test_the_column_pass_on_views_equals_the_row_pass_on_the_transpose():
    measured, image, _, _ = _scene(seed=5)
    none = np.zeros(measured.shape, dtype=bool)
    by_views, moved_views = edges._snap(measured, image, none, 3, 2.0, 8.0, along=0)
    by_copy, moved_copy = edges._snap(np.ascontiguousarray(measured.T),
                                      np.ascontiguousarray(image.T), none.T.copy(), 3, 2.0,
                                      8.0)
    assert _same(by_views, np.ascontiguousarray(by_copy.T))
    assert _same(moved_views, np.ascontiguousarray(moved_copy.T))
    assert moved_views.any()


@pytest.mark.parametrize("split", [2, 10 ** 9])
def test_a_speckle_region_cut_by_the_halves_is_counted_whole(monkeypatch, split):
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", split)
    field = np.full((80, 30), np.nan, dtype=np.float32)
    field[34:46, 5] = 7.0  # 12 px across rows 39 | 40 (the halves' edge): kept
    field[36:44, 10] = 9.0  # 8 px across the edge: removed
    steps = np.linspace(3.0, 8.5, 24, dtype=np.float32).reshape(12, 2)  # 0.5 px steps
    field[34:46, 15:17] = steps  # one region of 24 across the edge: kept
    field[38, 20], field[39, 20:26], field[40, 25] = 4.0, 4.0, 30.0  # the last pixel jumps: 7 + 1
    cleaned = remove_speckles(field, max_size=10, max_difference=1.0)
    assert np.isfinite(cleaned[34:46, 5]).all()
    assert np.isnan(cleaned[:, 10]).all()
    assert np.isfinite(cleaned[34:46, 15:17]).all()
    assert np.isnan(cleaned[38:41, 20:26]).all()


def test_the_noise_histogram_of_two_halves_is_the_whole_images(monkeypatch):
    rng = np.random.default_rng(4)
    image = np.clip(100 + 40 * np.sin(np.arange(97) / 9.0)[None, :]
                    + rng.normal(0, 4, (131, 97)), 0, 255).astype(np.uint8)
    valid = rng.random(image.shape) > 0.05
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", 10 ** 9)
    single = noise_sigma(image, valid)
    monkeypatch.setattr(disparity, "MIN_SPLIT_ROWS", 2)
    split = noise_sigma(image, valid)
    assert split == single
    assert 3.0 < single < 5.5  # σ = 4 grey levels (rounded to integers)


def test_the_vectorised_median_of_nine_is_the_windows_median_exactly():
    from numpy.lib.stride_tricks import sliding_window_view

    rng = np.random.default_rng(8)
    values = np.round(rng.normal(size=(70, 83)) * 4, 1).astype(np.float32)  # with ties
    values[rng.random(values.shape) < 0.03] = np.nan
    filtered = median_filter(values, 3)[1:-1, 1:-1]
    windows = sliding_window_view(values, (3, 3)).reshape(68, 81, 9)
    whole = np.isfinite(windows).all(axis=2)
    assert whole.mean() > 0.5
    assert np.array_equal(filtered[whole], np.median(windows[whole], axis=1))
    partial = ~whole & np.isfinite(values[1:-1, 1:-1])
    assert np.array_equal(filtered[partial], np.nanmedian(windows[partial], axis=1))


def test_threads_follow_the_workers_limit(monkeypatch):
    """`--workers 1` (a tile job, a Dask worker with one thread): one call in the caller's
    thread, inside the matcher's limit; the matcher sets the limit from its workers."""
    import threading

    from demtool.sgm.matcher import sgm
    from demtool.tiling import distributed, tasks
    from demtool.tiling.distributed import threads_limited

    calls: list[tuple[int, int, str]] = []

    def record(start, stop):
        calls.append((start, stop, threading.current_thread().name))

    with threads_limited(1):
        in_halves(record, 1000)
    assert calls == [(0, 1000, threading.current_thread().name)]
    calls.clear()
    with threads_limited(2):
        in_halves(record, 1000)
    if distributed.available_cores() >= 2:
        assert sorted(c[:2] for c in calls) == [(0, 500), (500, 1000)]
    # the matcher with workers=1: every post-processing split sees a limit of one thread
    limits: list[int] = []
    original = disparity.in_halves

    def spy(work, count, min_split=None):
        limits.append(distributed.usable_threads())
        return original(work, count, min_split)

    monkeypatch.setattr(disparity, "in_halves", spy)
    monkeypatch.setattr(edges, "in_halves", spy)
    rng = np.random.default_rng(0)
    left = rng.normal(100.0, 20.0, (96, 128)).astype(np.float32)
    right = np.roll(left, -4, axis=1)
    sgm(left, right, min_disparity=0, num_disparities=16, cost="census", workers=1)
    assert limits and set(limits) == {1}
    assert tasks._THREAD_LIMIT.get() == 0  # reset after the call


def test_concurrent_callers_run_their_second_halves_at_once(monkeypatch):
    """Tile threads split their rows at once: each has its own helper thread, so the two
    second halves run together (with one helper for the process, the second waited for
    the first, and the barrier below broke)."""
    import threading

    from demtool.tiling import rows

    monkeypatch.setattr(rows, "usable_threads", lambda: 2)
    both_second_halves = threading.Barrier(2, timeout=10)
    helpers: set[int] = set()
    errors: list[BaseException] = []

    def work(start: int, stop: int) -> None:
        if start > 0:  # a second half: waits until the other caller's runs too
            helpers.add(threading.get_ident())
            both_second_halves.wait()

    def caller() -> None:
        try:
            in_halves(work, 200, min_split=2)
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=caller) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert not errors, errors
    assert len(helpers) == 2  # two helper threads, one per caller
