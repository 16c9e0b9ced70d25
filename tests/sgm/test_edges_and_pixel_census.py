"""Depth edges moved back onto the image's edges, and the pixel census of cost "auto"
(issue 26)."""

from __future__ import annotations

import numpy as np

import demtool.sgm.matcher as matcher
from demtool.sgm import auto as rules
from demtool.sgm import sgm
from demtool.sgm.auto import blend, full_range, prefer_fine, prefer_gradient
from demtool.sgm.edges import snap_edges
from tests.helpers.sgm import error_rates, occlusion_pair, smooth_disparity_pair


def _step_image(edge: int, width: int = 20) -> np.ndarray:
    image = np.full((3, width), 50.0, dtype=np.float32)
    image[:, edge:] = 150.0  # the intensity edge between edge − 1 and edge
    return image


def test_a_fattened_foreground_moves_back_to_the_intensity_edge():
    disparity = np.full((3, 20), 4.0, dtype=np.float32)
    disparity[:, 7:] = 10.0  # the foreground (from x = 10 in the image) fattened by 3 px
    out, moved = snap_edges(disparity, _step_image(10), 4, min_step=20.0)
    assert np.allclose(out[:, :10], 4.0) and np.allclose(out[:, 10:], 10.0)
    assert moved[:, 7:10].all() and moved.sum() == 9
    # beyond the radius, or an intensity step below min_step: no edge, nothing moves
    for radius, min_step in ((2, 20.0), (4, 200.0)):
        out, moved = snap_edges(disparity, _step_image(10), radius, min_step=min_step)
        assert not moved.any() and np.array_equal(out, disparity)


def test_a_foreground_fattened_to_the_right_moves_back_too():
    disparity = np.full((3, 20), 4.0, dtype=np.float32)
    disparity[:, :13] = 10.0  # foreground up to x = 9 in the image, fattened to x = 12
    out, moved = snap_edges(disparity, _step_image(10), 4, min_step=20.0)
    assert np.allclose(out[:, :10], 10.0) and np.allclose(out[:, 10:], 4.0)
    assert moved[:, 10:13].all() and moved.sum() == 9


def test_a_foreground_fattened_into_an_occlusion_joins_it():
    disparity = np.full((3, 20), 10.0, dtype=np.float32)
    disparity[:, :4] = 4.0
    disparity[:, 4:7] = np.nan  # the check found x = 4 … 6 occluded; the image edge: 9 | 10
    occluded = np.isnan(disparity)
    out, moved = snap_edges(disparity, _step_image(10), 4, occluded, min_step=20.0)
    assert np.isnan(out[:, 4:10]).all() and np.allclose(out[:, 10:], 10.0)
    assert moved[:, 7:10].all() and moved.sum() == 9
    # an invalid run the check did not call occluded is left as it is
    out, moved = snap_edges(disparity, _step_image(10), 4, np.zeros_like(occluded),
                            min_step=20.0)
    assert not moved.any()


def _bright_box_pair():
    """:func:`occlusion_pair` with the box 300 grey levels brighter: a clear edge."""
    left, right, truth, _ = occlusion_pair(noise=0.5)  # box rows 30:66, columns 56:100, d 14
    rows, cols = np.mgrid[0:left.shape[0], 0:left.shape[1]]
    in_rows = (rows >= 30) & (rows < 66)
    left = left + 300.0 * (in_rows & (cols >= 56) & (cols < 100))
    right = right + 300.0 * (in_rows & (cols + 14 >= 56) & (cols + 14 < 100))
    return left.astype(np.float32), right.astype(np.float32), truth


def test_snapping_lowers_the_errors_at_a_boxes_borders(monkeypatch):
    left, right, truth = _bright_box_pair()
    scored = np.zeros(truth.shape, dtype=bool)
    scored[4:-4, 20:-4] = True
    snapped = sgm(left, right, min_disparity=0, num_disparities=20, cost="census", workers=1)
    monkeypatch.setattr(matcher, "snap_edges",
                        lambda disparity, *args, **kwargs: (
                            disparity, np.zeros(disparity.shape, dtype=bool)))
    plain = sgm(left, right, min_disparity=0, num_disparities=20, cost="census", workers=1)
    bad_snapped = error_rates(snapped.disparity, truth, scored)["bad1"]
    bad_plain = error_rates(plain.disparity, truth, scored)["bad1"]
    assert bad_snapped < 0.8 * bad_plain, (bad_snapped, bad_plain)


def test_blend_averages_where_the_costs_agree_and_keeps_census_elsewhere():
    fine = np.array([[4.0, 4.0, 4.0, np.nan]], dtype=np.float32)
    hmi = np.array([[4.5, 9.0, np.nan, 4.0]], dtype=np.float32)
    out = blend(fine, hmi)
    assert np.allclose(out[0, :3], [4.25, 4.0, 4.0]) and np.isnan(out[0, 3])


def test_prefer_fine_refuses_a_pixel_census_that_is_much_less_consistent():
    valid = np.ones((10, 10), dtype=bool)
    good = np.full((10, 10), 5.0, dtype=np.float32)
    holes = good.copy()
    holes[:2] = np.nan  # 80 % consistent against 100 %
    assert "80.0 %" in prefer_fine(holes, good, valid)
    assert prefer_fine(good, holes, valid) == ""
    assert prefer_fine(good[:, :], good, valid) == ""


def test_auto_keeps_the_windowed_choice_without_depth_discontinuities():
    """A clean pair of smooth disparities (terrain-like): no discontinuity, so no pixel
    census — on smooth ground its single-pixel costs are the noisier (issue 26)."""
    left, right, truth = smooth_disparity_pair(offset=6.0, gain=1.3, bias=50.0)
    auto = sgm(left, right, min_disparity=0, num_disparities=16, workers=1)
    assert not auto.fractions["cost_used"].startswith("census+")
    assert auto.fractions["noise_sigma"] <= 5.0
    scored = np.zeros(truth.shape, dtype=bool)
    scored[4:-4, 20:-4] = True
    assert error_rates(auto.disparity, truth, scored)["bad2"] < 0.01


def test_auto_uses_the_pixel_census_near_a_clean_pairs_depth_discontinuity():
    left, right, truth, occluded = occlusion_pair(noise=0.5)
    auto = sgm(left, right, min_disparity=0, num_disparities=24, workers=1)
    assert auto.fractions["noise_sigma"] <= 5.0
    assert auto.fractions["cost_used"].startswith("census+")
    assert 0.0 < auto.fractions["edge_census"] < 1.0
    scored = np.zeros(truth.shape, dtype=bool)
    scored[2:-2, 24:-2] = True
    assert error_rates(auto.disparity, truth, scored & ~occluded)["bad2"] < 0.02


def test_prefer_gradient_only_when_more_consistent_than_both():
    valid = np.ones((10, 10), dtype=bool)
    good = np.full((10, 10), 5.0, dtype=np.float32)
    holes = good.copy()
    holes[:3] = np.nan
    assert "100.0 %" in prefer_gradient(good, holes, holes, valid)
    assert prefer_gradient(good, good, holes, valid) == ""  # not more than HMI's
    assert prefer_gradient(holes, good, holes, valid) == ""


def test_full_range_leaves_out_the_columns_where_the_range_leaves_the_image():
    valid = np.ones((2, 10), dtype=bool)
    assert np.flatnonzero(full_range(valid, 0, 4)[0]).tolist() == list(range(3, 10))
    assert np.flatnonzero(full_range(valid, -2, 4)[0]).tolist() == list(range(1, 8))


def test_the_gradient_cost_ignores_gain_and_offset(monkeypatch):
    left, right, truth = smooth_disparity_pair(offset=6.0, gain=1.3, bias=50.0)
    monkeypatch.setattr(rules, "FINE_NOISE_MAX", -1.0)  # the noisy branch
    monkeypatch.setattr(rules, "prefer_gradient", lambda *args: "as if more consistent")
    auto = sgm(left, right, min_disparity=0, num_disparities=16, workers=1)
    assert auto.fractions["cost_used"] == "gradient"
    assert auto.fractions["cost_reason"] == "as if more consistent"
    scored = np.zeros(truth.shape, dtype=bool)
    scored[4:-4, 20:-4] = True
    assert error_rates(auto.disparity, truth, scored)["bad2"] < 0.02
