"""Tile margins from the path reach (demtool.sgm.margins) and the phase timer's CPU."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from demtool.sgm import cost as costs
from demtool.sgm import margins
from demtool.sgm.matcher import sgm
from demtool.sgm.params import SgmParams
from demtool.sgm.passes import census_cost
from demtool.sgm.strips import PhaseTimer
from demtool.sgm.tiled import default_tile_size


def textured_pair(size: int, contrast: float, seed: int = 0):
    """A band-limited texture and its copy shifted by a smooth 6 … 14 px disparity."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    base = ndimage.gaussian_filter(rng.normal(size=(size, size + 32)), 1.2)
    base = 500 + contrast * base / base.std()
    ys, xs = np.mgrid[0:size, 0:size].astype(float)
    disparity = 10 + 4 * np.sin(2 * np.pi * xs / size) * np.cos(2 * np.pi * ys / size)
    left = (base[:, :size] + rng.normal(0, 1.0, (size, size))).astype(np.float32)
    right = ndimage.map_coordinates(base, [ys, xs + disparity], order=3)
    right = (right + rng.normal(0, 1.0, (size, size))).astype(np.float32)
    return left, right


def test_path_reach_is_kappa_p2_over_the_contrast():
    assert margins.path_reach(1200, 150.0) == 32  # ⌈4 · 1200 / 150⌉
    assert margins.path_reach(1200, 149.0) == 33
    assert margins.path_reach(600, 10.0) == 240  # weak texture: long memory
    with pytest.raises(ValueError, match="positive"):
        margins.path_reach(1200, 0.0)


def test_contrast_samples_equal_the_kernels_cost_volume():
    left, right = textured_pair(64, 6.0)
    left[20:24, 40:44] = np.nan  # invalid pixels are left out
    got = margins.contrast_samples(left, right, cost="census", window=5,
                                   census_shape=(5, 5), min_disparity=2,
                                   num_disparities=20)
    lv, rv = np.isfinite(left), np.isfinite(right)
    volume = costs.windowed_cost_volume(census_cost(left, right, lv, rv, (5, 5), 1), lv, rv,
                                        min_disparity=2, num_disparities=20, window=5,
                                        rows=(0, 64)).astype(float)
    inner = (slice(2, 62), slice(2 + 21, 62))  # window inside, every match inside
    from scipy import ndimage

    whole = ndimage.minimum_filter(lv.astype(np.uint8), 5, mode="constant")[inner] > 0
    values = volume[inner][whole]  # pixels whose whole window is valid
    np.testing.assert_array_equal(got, values.mean(axis=1) - values.min(axis=1))


def test_weak_texture_gets_a_longer_margin_than_strong():
    params = SgmParams(cost="census")
    strong = margins.cost_contrast([textured_pair(96, 8.0)], cost="census", window=5,
                                   census_shape=(5, 5), min_disparity=0, num_disparities=24)
    weak = margins.cost_contrast([textured_pair(96, 0.7)], cost="census", window=5,
                                 census_shape=(5, 5), min_disparity=0, num_disparities=24)
    assert weak < strong
    wide, made = margins.tile_margin(params, {"census": weak})
    narrow, _ = margins.tile_margin(params, {"census": strong})
    assert wide > narrow
    assert made["contrast_source"] == "measured"
    assert made["margin_px"] == wide == (made["path_reach_px"] + 2 * made["support_px"]
                                         + made["median_px"] + made["speckle_px"])
    modelled, made = margins.tile_margin(params)  # nothing measured: a weak texture
    assert made["contrast_source"] == "model" and modelled >= narrow
    # the MI costs keep the fixed 64 px + windows (their tiles' MI tables are their own)
    assert margins.tile_margin(SgmParams(cost="hmi"))[0] == 64 + 3 + 5 + 3 + 10


def test_a_tile_with_the_derived_margin_matches_the_untiled_core():
    left, right = textured_pair(160, 8.0, seed=3)
    options = dict(min_disparity=0, num_disparities=24, cost="census", workers=1)
    untiled = sgm(left, right, **options).disparity
    contrast = margins.cost_contrast([(left, right)], cost="census", window=5,
                                     census_shape=(5, 5), min_disparity=0,
                                     num_disparities=24)
    margin, _ = margins.tile_margin(SgmParams(cost="census"), {"census": contrast})
    assert margin < 64 + 5 + 5 + 3 + 10  # shorter than the old fixed margin
    r0, c0, core = 60, 70, 40  # a core in the middle; the window: margins + range
    rows = slice(max(0, r0 - margin), min(160, r0 + core + margin))
    cols = slice(max(0, c0 - margin - 23), min(160, c0 + core + margin))
    tiled = sgm(left[rows, cols], right[rows, cols], **options).disparity
    got = tiled[r0 - rows.start:r0 - rows.start + core, c0 - cols.start:c0 - cols.start + core]
    want = untiled[r0:r0 + core, c0:c0 + core]
    same = (got == want) | (np.isnan(got) & np.isnan(want))
    assert same.mean() >= 0.999, same.mean()


def test_default_tile_size_fits_the_budget_and_shrinks_with_workers():
    params = SgmParams(cost="census")
    one, two = default_tile_size(params, 96), default_tile_size(params, 96, 2)
    assert one % 256 == 0 and two % 256 == 0 and one > two >= 512
    margin = margins.tile_margin(params)[0]
    side = one + 2 * margin
    assert side * (side + 96) * 96 * 2 <= params.max_memory_mb * 2**20


def test_phase_timer_counts_the_helper_threads_cpu():
    timer = PhaseTimer()

    def spin(seconds: float) -> None:
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass

    with timer.measure("postprocess"):
        helper = threading.Thread(target=spin, args=(0.2,))
        helper.start()
        spin(0.2)
        helper.join()
    assert timer.seconds["postprocess_cpu"] >= 0.38
    with timer.waiting("match"):
        time.sleep(0.01)
    assert timer.seconds["match_wait"] >= 0.01
