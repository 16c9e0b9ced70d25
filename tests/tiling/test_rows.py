"""demtool.tiling.rows: a nogil row kernel over parts of its rows on the calling thread
and its helpers, within the caller's thread limits."""

from __future__ import annotations

import threading
import time

import numba
import numpy as np
import pytest

from demtool.tiling import rows
from demtool.tiling.rows import on_row_parts, ordered_map, row_parts
from demtool.tiling.tasks import numba_threads_at_most, threads_limited, usable_threads


@numba.njit(nogil=True, cache=True)
def _cumulate_rows(values, out, start, stop):
    for y in range(start, stop):
        total = 0.0
        for x in range(values.shape[1]):
            total += values[y, x] * (x + 1)
            out[y, x] = total


def test_parts_cover_the_rows_once_in_order(monkeypatch):
    monkeypatch.setattr(rows, "usable_threads", lambda: 4)
    with numba_threads_at_most(1):
        assert row_parts(1000) == [(0, 1000)]  # numba's count of this thread: one
    monkeypatch.setattr(rows, "_numba_threads", lambda: 4)
    assert row_parts(1000) == [(0, 250), (250, 500), (500, 750), (750, 1000)]
    assert row_parts(1000, max_parts=2) == [(0, 500), (500, 1000)]
    assert row_parts(150, min_rows=64) == [(0, 75), (75, 150)]  # 2 parts of ≥ 64 rows
    assert row_parts(100, min_rows=64) == [(0, 100)]
    assert row_parts(0) == [(0, 0)]


def test_a_threads_limit_of_one_keeps_the_work_on_the_calling_thread():
    calls = []
    with threads_limited(1):
        on_row_parts(lambda start, stop: calls.append((start, stop,
                                                       threading.current_thread().name)),
                     1000, min_rows=1)
    assert calls == [(0, 1000, threading.current_thread().name)]


def test_split_rows_give_the_one_thread_result_bit_for_bit(monkeypatch):
    values = np.random.default_rng(3).normal(size=(301, 97))
    single = np.empty_like(values)
    _cumulate_rows(values, single, 0, values.shape[0])
    monkeypatch.setattr(rows, "usable_threads", lambda: 3)
    monkeypatch.setattr(rows, "_numba_threads", lambda: 3)
    seen = []

    def work(start, stop):
        seen.append((start, stop))
        _cumulate_rows(values, split, start, stop)

    split = np.full_like(values, np.nan)
    on_row_parts(work, values.shape[0], min_rows=8)
    assert sorted(seen) == [(0, 100), (100, 200), (200, 301)]
    assert np.array_equal(single.view(np.uint8), split.view(np.uint8))


def test_a_failing_part_is_raised_after_every_part_ended(monkeypatch):
    monkeypatch.setattr(rows, "usable_threads", lambda: 2)
    monkeypatch.setattr(rows, "_numba_threads", lambda: 2)
    ended = []

    def work(start, stop):
        if start > 0:
            raise ValueError(f"rows {start}-{stop} failed")
        ended.append(start)

    with pytest.raises(ValueError, match="rows 50-100 failed"):
        on_row_parts(work, 100, min_rows=1)
    assert ended == [0]


def test_ordered_map_runs_each_call_in_the_callers_context():
    """A pool thread of ordered_map sees the calling thread's threads_limited limit (a
    fresh thread would see none) and leaving the loop early cancels what has not
    started."""
    started = []

    def call(item):
        started.append(item)
        return item, usable_threads(), threading.current_thread().name

    with threads_limited(2):
        got = list(ordered_map(call, range(6), threads=2))
    assert [item for item, _, _ in got] == list(range(6))
    assert {limit for _, limit, _ in got} == {min(2, usable_threads())}
    assert all(name.startswith("demtool") for _, _, name in got)
    started.clear()
    results = ordered_map(lambda item: (time.sleep(0.02), started.append(item)), range(50),
                          threads=2)
    next(results)
    results.close()
    assert len(started) < 50
