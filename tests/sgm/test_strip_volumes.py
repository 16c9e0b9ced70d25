"""Strips of one SGM pass share their aggregated-cost volumes S (issue 47): the
disparity is exactly that of strips each given a fresh volume."""

import numpy as np
import pytest

from demtool.sgm import cost as costs
from demtool.sgm import strips
from demtool.sgm.strips import PhaseTimer, match_pass, plan_strips, sweep_state_bytes
from demtool.sgm.volumes import reusing_volumes


def _pass(workers: int, budget_rows: int, paths: int):
    rng = np.random.default_rng(5)
    height, width, n_disp, window = 300, 40, 12, 3
    base = rng.integers(0, 255, size=(height, width + n_disp)).astype(np.float32)
    left = base[:, n_disp:]
    right = base[:, n_disp - 5:-5] + rng.normal(0, 3, (height, width)).astype(np.float32)
    valid = np.ones((height, width), dtype=bool)
    pixel_cost = costs.census_pixel_cost(left, right, (5, 5))
    guide = costs.quantize(left, valid, 256)
    concurrent = max(1, workers // 2)
    fixed = 2 * sweep_state_bytes(width, n_disp, paths, window)
    budget = (fixed + budget_rows * width * n_disp * 2) * concurrent / 2**20
    plan = plan_strips(height, width, n_disp, workers=concurrent, max_memory_mb=budget,
                       fixed_bytes=fixed, threads=1 if workers < 2 else 2)
    disparity, confidence = match_pass(
        pixel_cost, valid, valid, guide, min_disparity=0, num_disparities=n_disp,
        window=window, p1=5, p2=60, paths=paths, p2_kappa=8, subpixel="equiangular",
        lr_threshold=1.0, workers=workers, max_memory_mb=budget, unmatched_fraction=0.5,
        timer=PhaseTimer())
    return len(plan), disparity, confidence


@pytest.mark.parametrize("workers", [1, 2, 4])
@pytest.mark.parametrize("paths", [8, 16])
def test_strips_sharing_volumes_match_strips_with_fresh_ones(workers, paths, monkeypatch):
    n_strips, disparity, confidence = _pass(workers, 90, paths)
    assert n_strips >= 4  # several strips, run one after the other or two at once
    original = strips.match_strip
    fresh_calls = []

    def fresh(*args, total=None, **kwargs):  # the volume as before: a new one per strip
        fresh_calls.append(total.shape if total is not None else None)
        volume = np.full_like(total, 65535) if total is not None else None
        return original(*args, total=volume, **kwargs)

    monkeypatch.setattr(strips, "match_strip", fresh)
    _, expected, expected_confidence = _pass(workers, 90, paths)
    assert len(fresh_calls) == n_strips
    assert np.array_equal(disparity, expected, equal_nan=True)
    assert np.array_equal(confidence, expected_confidence, equal_nan=True)
    assert np.isfinite(disparity).mean() > 0.5


def _one_strip(seed: int, height: int):
    """One pass of a small pair that fits one strip (single-strip passes use the pool)."""
    rng = np.random.default_rng(seed)
    width, n_disp = 48, 16
    base = rng.integers(0, 255, size=(height, width + n_disp)).astype(np.float32)
    left, right = base[:, n_disp:], base[:, n_disp - 6:-6]
    valid = np.ones((height, width), dtype=bool)
    return match_pass(
        costs.census_pixel_cost(left, right, (5, 5)), valid, valid,
        costs.quantize(left, valid, 256), min_disparity=0, num_disparities=n_disp,
        window=3, p1=5, p2=60, paths=8, p2_kappa=8, subpixel="equiangular",
        lr_threshold=1.0, workers=2, max_memory_mb=64.0, unmatched_fraction=0.5,
        timer=PhaseTimer())


def test_passes_reusing_their_thread_volume_match_fresh_volumes():
    # tiles of a run reuse their thread's S (issue 47): a smaller pass gets the larger
    # volume of the one before, holding its sums; a larger one maps a new volume
    cases = [(1, 120), (2, 80), (3, 150), (4, 150)]
    expected = [_one_strip(*case) for case in cases]
    with reusing_volumes() as pool:
        reused = [_one_strip(*case) for case in cases]
        assert pool.mapped == 2
    assert not pool._held  # dropped at the end of the block
    for (disparity, confidence), (want, want_confidence) in zip(reused, expected,
                                                                strict=True):
        assert np.isfinite(want).mean() > 0.5
        assert np.array_equal(disparity, want, equal_nan=True)
        assert np.array_equal(confidence, want_confidence, equal_nan=True)
