"""Exact memory-saving schedules of the SGM sweeps (issue 28): a strip whose aggregated
cost S does not fit the budget recomputes the end rows of its sweeps instead of being
cut into overlapping strips, with exactly the same result."""

import numpy as np
import pytest

from demtool.errors import ParameterError
from demtool.sgm import cost as costs
from demtool.sgm import strips
from demtool.sgm.matcher import sgm
from demtool.sgm.strips import (
    PhaseTimer,
    match_strip,
    plan_strips,
    recompute_rows,
    stored_rows_of_pass,
)
from tests.helpers.sgm import smooth_disparity_pair


def _strip(rows, threads, recompute, paths, cost):
    rng = np.random.default_rng(3)
    height, width, n_disp = rows, 40, 12
    base = rng.integers(0, 255, size=(height, width + n_disp)).astype(np.float32)
    left = base[:, n_disp:]
    right = base[:, n_disp - 5:-5] + rng.normal(0, 3, (height, width)).astype(np.float32)
    valid = np.ones((height, width), dtype=bool)
    if cost == "census":
        pixel_cost = costs.census_pixel_cost(left, right, (5, 5))
    else:
        levels = [costs.quantize(image, valid, 32) for image in (left, right)]
        table = costs.absolute_difference_table(32, 10)
        pixel_cost = costs.table_pixel_cost("ad", *levels, table)
    source = pixel_cost.kernel_source(valid, valid, 0)
    guide = np.ascontiguousarray(costs.quantize(left, valid, 256), dtype=np.uint8)
    return match_strip(source, 1, guide, n_disp=n_disp, paths=paths, p1=5, p2=60,
                       p2_kappa=8, rows=(0, height), out_rows=(0, height),
                       subpixel="equiangular", lr_threshold=1.0, threads=threads,
                       timer=PhaseTimer(), recompute=recompute)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("paths", [8, 16])
@pytest.mark.parametrize("cost", ["census", "ad"])
def test_recomputed_end_rows_give_exactly_the_stored_result(threads, paths, cost):
    rows = 23
    expected = _strip(rows, threads, 0, paths, cost)
    # the smallest budget: S of rows − 2·(rows // 4) rows (two threads), rows − rows // 2 (one)
    budget = rows - 2 * (rows // 2 // 2) if threads > 1 else rows - rows // 2
    most = recompute_rows(rows, budget, threads)
    assert most > 0
    for q in sorted({1, 3, most}):
        got = _strip(rows, threads, q, paths, cost)
        assert np.array_equal(expected[0], got[0], equal_nan=True), q
        assert np.array_equal(expected[1], got[1], equal_nan=True), q
    # and the two schedules agree with each other (the sums do not depend on threads)
    assert np.array_equal(expected[0], _strip(rows, 3 - threads, 0, paths, cost)[0],
                          equal_nan=True)


def test_recompute_rows_fit_the_budget():
    assert recompute_rows(100, 100, 2) == 0
    assert recompute_rows(100, 70, 2) == 15  # S holds 100 − 2·15 rows
    assert recompute_rows(100, 70, 1) == 30  # S holds 100 − 30 rows
    assert recompute_rows(100, 50, 2) == 25
    with pytest.raises(ParameterError, match="max-memory-mb"):
        recompute_rows(100, 49, 2)
    with pytest.raises(ParameterError, match="max-memory-mb"):
        recompute_rows(100, 49, 1)


def test_a_2048_square_in_700_mib_is_one_exact_strip():
    # 2048² × 128 needs 1 GiB of S: in 700 MiB the two sweeps recompute 1/6 of the rows
    # each instead of cutting the image into strips whose paths restart at their edges
    for threads in (1, 2):
        one = plan_strips(2048, 2048, 128, workers=1, max_memory_mb=700, threads=threads)
        assert one == [(0, 2048)]
        # under half of S (plus the buffers): strips again
        assert len(plan_strips(2048, 2048, 128, workers=1, max_memory_mb=500,
                               threads=threads)) > 1


def test_held_results_count_against_the_budget_of_a_single_strip_only():
    # 2048² × 128 in 640 MiB: one strip storing 1238 rows; 72 MiB held (two results of
    # cost "auto") take 144 rows more off, never below the 1024 rows it must store
    args = dict(workers=1, max_memory_mb=640, fixed_bytes=2 * 2**20, threads=2)
    alone = stored_rows_of_pass(2048, 2048, 128, single=True, **args)
    held = stored_rows_of_pass(2048, 2048, 128, single=True, held_bytes=72 * 2**20, **args)
    assert alone == 1276 and held == alone - 144
    assert stored_rows_of_pass(2048, 2048, 128, single=True, held_bytes=2**30, **args) == 1024
    # several strips are never cut differently: their overlaps would change the disparity
    assert stored_rows_of_pass(2048, 2048, 128, single=False, held_bytes=2**30,
                               **args) == alone


def test_auto_holding_results_in_a_small_budget_gives_exactly_the_same_disparity(monkeypatch):
    # cost "auto" keeps earlier passes' results while it runs the next: within 1 MiB their
    # bytes make the sweeps recompute more end rows, with exactly the same result
    left, right, _ = smooth_disparity_pair(height=200, width=96, offset=0.0)
    whole = sgm(left, right, min_disparity=-12, num_disparities=24, workers=2)
    recomputed = []
    original = strips.recompute_rows

    def recording(rows, budget, threads):
        recomputed.append(q := original(rows, budget, threads))
        return q

    monkeypatch.setattr(strips, "recompute_rows", recording)
    small = sgm(left, right, min_disparity=-12, num_disparities=24, workers=2,
                max_memory_mb=1.0)
    assert len(set(recomputed)) > 1 and max(recomputed) > 0  # held results: more rows
    assert small.fractions["cost_used"] == whole.fractions["cost_used"]
    assert np.array_equal(whole.disparity, small.disparity, equal_nan=True)
    assert np.array_equal(whole.confidence, small.confidence, equal_nan=True)
