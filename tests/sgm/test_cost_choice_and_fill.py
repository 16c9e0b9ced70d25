"""The default cost on weak texture, the MI fallback, the fill and the class raster
(issue 26)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from demtool.sgm import auto as rules
from demtool.sgm import sgm
from demtool.sgm.auto import prefer_census as _prefer_census
from demtool.sgm.fill import (
    AT_BOUND,
    FILLED_MISMATCH,
    FILLED_OCCLUSION,
    INVALID,
    MATCHED,
    _grow_regions,
    class_fractions,
    classify,
    fill_classified,
    occluded_regions,
)
from tests.helpers.sgm import error_rates, occlusion_pair, plank_pair, smooth_disparity_pair


def test_auto_replaces_hmi_by_census_on_a_weak_texture_plank(caplog, monkeypatch):
    left, right, truth = plank_pair()  # plank texture σ 1 grey level, range 0 … 47
    scored = np.zeros(truth.shape, dtype=bool)
    scored[:, 48:] = True  # every disparity of the range lands inside the right image
    hmi = sgm(left, right, min_disparity=0, num_disparities=48, cost="hmi", workers=1)
    bad_hmi = error_rates(hmi.disparity, truth, scored)["bad2"]
    # the image's noise (σ ≈ 4 grey levels of the stretch) lets the pixel census try
    pixel = sgm(left, right, min_disparity=0, num_disparities=48, workers=1)
    # near its depth discontinuities (the plank's borders): the windowed choice elsewhere
    assert pixel.fractions["cost_used"].startswith("census+")
    bad_pixel = error_rates(pixel.disparity, truth, scored)["bad2"]
    assert bad_pixel < 0.5 * bad_hmi and bad_pixel < 0.15, (bad_hmi, bad_pixel)
    monkeypatch.setattr(rules, "FINE_NOISE_MAX", -1.0)  # as if the image were noisier
    gradient = sgm(left, right, min_disparity=0, num_disparities=48, workers=1)
    assert gradient.fractions["cost_used"] == "gradient"  # the most consistent here
    bad_gradient = error_rates(gradient.disparity, truth, scored)["bad2"]
    assert bad_gradient < 0.5 * bad_hmi and bad_gradient < 0.15, (bad_hmi, bad_gradient)
    monkeypatch.setattr(rules, "prefer_gradient", lambda *args: "")  # without it: census
    with caplog.at_level(logging.INFO, logger="demtool"):
        windowed = sgm(left, right, min_disparity=0, num_disparities=48, workers=1)
    assert windowed.parameters["cost"] == "auto"
    assert windowed.fractions["cost_used"] == "census"
    assert any("census instead of HMI" in r.getMessage() for r in caplog.records)
    bad_windowed = error_rates(windowed.disparity, truth, scored)["bad2"]
    assert bad_windowed < 0.5 * bad_hmi and bad_windowed < 0.15, (bad_hmi, bad_windowed)


def test_auto_keeps_the_hmi_matches_census_confirms_on_a_noisy_pair(monkeypatch):
    left, right, truth = smooth_disparity_pair(offset=6.0, gain=1.3, bias=50.0)
    monkeypatch.setattr(rules, "FINE_NOISE_MAX", -1.0)  # as if the image were noisy
    auto = sgm(left, right, min_disparity=0, num_disparities=16, workers=1)
    hmi = sgm(left, right, min_disparity=0, num_disparities=16, cost="hmi", workers=1)
    assert auto.fractions["cost_used"] == "hmi+census"
    kept = auto.classes == MATCHED
    assert kept.mean() > 0.8 and np.array_equal(auto.disparity[kept], hmi.disparity[kept])
    scored = np.zeros(truth.shape, dtype=bool)
    scored[4:-4, 20:-4] = True
    assert error_rates(auto.disparity, truth, scored)["bad2"] < 0.01


def test_auto_keeps_hmi_alone_where_census_disagrees(monkeypatch):
    left, right, _ = smooth_disparity_pair(offset=6.0, gain=1.3, bias=50.0)
    monkeypatch.setattr(rules, "FINE_NOISE_MAX", -1.0)
    monkeypatch.setattr(rules, "AUTO_AGREEMENT", 1.01)  # no agreement is enough
    auto = sgm(left, right, min_disparity=0, num_disparities=16, workers=1)
    hmi = sgm(left, right, min_disparity=0, num_disparities=16, cost="hmi", workers=1)
    assert auto.fractions["cost_used"] == "hmi"
    assert np.array_equal(auto.disparity, hmi.disparity, equal_nan=True)


def test_prefer_census_reasons():
    valid = np.ones((10, 10), dtype=bool)
    good = np.full((10, 10), 5.0, dtype=np.float32)
    holes = good.copy()
    holes[:3] = np.nan  # HMI left-right consistent on 70 %, census on 100 %
    assert "left-right consistent 100.0 %" in _prefer_census(holes, good, valid, 0, 16)
    assert _prefer_census(good, holes, valid, 0, 16) == ""
    pinned = good.copy()
    pinned[:2] = 0.0  # 20 % at the range's lower bound
    assert "at a bound" in _prefer_census(pinned, good, valid, 0, 16)
    assert _prefer_census(good, good, valid, 0, 16) == ""


@pytest.mark.parametrize("cost", ["hmi", "auto", "mi"])
def test_no_mi_histogram_pairs_falls_back_to_census(cost, caplog):
    left, right, _ = smooth_disparity_pair()
    left = left.copy()
    right = right.copy()
    left[:, 60:] = np.nan  # no valid left pixel x has a valid right pixel x − d, d 0 … 7
    right[:, :70] = np.nan
    with caplog.at_level(logging.WARNING, logger="demtool"):
        result = sgm(left, right, min_disparity=0, num_disparities=8, cost=cost, workers=1)
    assert result.fractions["cost_used"] == "census"
    assert "no valid corresponding pixels for the MI histogram" in result.fractions[
        "cost_reason"]
    assert any("with the census cost instead" in r.getMessage() for r in caplog.records)
    assert np.isnan(result.disparity).all()  # nothing can match, and nothing is refused


def test_occluded_regions_widen_along_the_row_by_the_disparity_jump():
    disparity = np.full((1, 20), np.nan, dtype=np.float32)
    disparity[0, :5] = 4.0  # background, then 10 invalid pixels, then the foreground
    disparity[0, 15:] = 10.0
    invalid = ~np.isfinite(disparity)
    occluded = np.zeros_like(invalid)
    occluded[0, 8] = True  # the left-right check found one of them occluded
    regions = occluded_regions(disparity, invalid, occluded)
    # the occlusion is 10 − 4 = 6 px wide from the visible background on
    assert np.flatnonzero(regions[0]).tolist() == [5, 6, 7, 8, 9, 10]
    assert not occluded_regions(disparity, invalid, np.zeros_like(invalid)).any()


def test_grown_regions_are_the_8_connected_components_holding_a_seed():
    # the regions scipy.ndimage.label numbers (8-connected) that hold a seed pixel
    from scipy import ndimage

    rng = np.random.default_rng(4)
    for _ in range(50):
        shape = tuple(rng.integers(1, 30, 2))
        inside = rng.random(shape) < rng.uniform(0.2, 0.8)
        seeds = inside & (rng.random(shape) < 0.05)
        labels, count = ndimage.label(inside, structure=np.ones((3, 3), dtype=bool))
        expected = np.isin(labels, np.unique(labels[seeds])) & inside
        grown = np.zeros(shape, dtype=bool)
        _grow_regions(inside, seeds, grown)
        assert np.array_equal(grown, expected)
    diagonal = np.eye(5, dtype=bool)  # corners touch: one region
    grown = np.zeros_like(diagonal)
    _grow_regions(diagonal, np.pad([[True]], ((0, 4), (0, 4))), grown)
    assert np.array_equal(grown, diagonal)


def test_foreground_fattened_into_an_occlusion_is_refilled_as_background():
    disparity = np.full((1, 24), 4.0, dtype=np.float32)  # background 4, foreground 10
    disparity[0, 7:] = 10.0
    disparity[0, 5:7] = np.nan  # the check found 2 of the 6 occluded pixels
    occluded = np.isnan(disparity)
    out, classes = fill_classified(disparity, occluded, np.ones_like(occluded))
    # the occlusion after the last background pixel (x = 4) is 10 − 4 = 6 px wide:
    # x = 5 … 10, so x = 7 … 10 (matched at 10: fattened) become background too
    assert np.allclose(out[0, 5:11], 4.0) and np.allclose(out[0, 11:], 10.0)
    assert (classes[0, 5:11] == FILLED_OCCLUSION).all() and (classes[0, 11:] == MATCHED).all()
    # without an occluded pixel in the gap nothing is taken for fattening
    out, classes = fill_classified(disparity, np.zeros_like(occluded), np.ones_like(occluded))
    assert np.allclose(out[0, 7:], 10.0) and (classes[0, 5:7] == FILLED_MISMATCH).all()


def test_fill_classified_background_for_occlusions_median_for_mismatches():
    left, right, truth, occluded = occlusion_pair()  # background 4, box 14
    raw = sgm(left, right, min_disparity=0, num_disparities=20, cost="census", fill=False,
              workers=1)
    filled = sgm(left, right, min_disparity=0, num_disparities=20, cost="census", workers=1)
    hole = occluded & np.isnan(raw.disparity)
    assert hole.sum() > 0.5 * occluded.sum()
    assert np.mean(filled.classes[hole] == FILLED_OCCLUSION) > 0.9
    assert np.mean(np.abs(filled.disparity[hole] - 4.0) < 1.0) > 0.9
    matched = np.isfinite(raw.disparity)
    kept = np.isin(filled.classes, (MATCHED, AT_BOUND))
    # every matched pixel stays matched, except foreground fattened into the occlusion
    refilled = matched & ~kept
    assert (filled.classes[refilled] == FILLED_OCCLUSION).all()
    assert refilled.sum() < 0.01 * matched.sum()
    # fractions of the valid left image, one per class, adding up to 1
    fractions = filled.fractions
    assert abs(sum(fractions[k] for k in ("invalid", "matched", "filled_occlusion",
                                          "filled_mismatch", "at_range_bound")) - 1) < 1e-3
    assert fractions["matched"] == pytest.approx((matched & kept).mean(), abs=2e-3)
    # a mismatch far from any occlusion takes the median of its neighbours
    disparity = np.full((9, 9), 3.0, dtype=np.float32)
    disparity[4, 4] = np.nan
    disparity[:, 7:] = 8.0
    out, classes = fill_classified(disparity, np.zeros((9, 9), bool), np.ones((9, 9), bool))
    assert out[4, 4] == 3.0 and classes[4, 4] == FILLED_MISMATCH
    assert (classes[np.isfinite(disparity)] == MATCHED).all()


def test_no_fill_is_unchanged_and_classes_mark_the_invalid():
    left, right, truth, occluded = occlusion_pair()
    raw = sgm(left, right, min_disparity=0, num_disparities=20, cost="census", fill=False,
              workers=1)
    assert raw.parameters["fill"] is False
    assert np.array_equal(raw.classes == INVALID, np.isnan(raw.disparity))
    assert raw.fractions["filled_occlusion"] == 0 and raw.fractions["filled_mismatch"] == 0


def test_classify_marks_range_bounds():
    disparity = np.array([[0.2, 0.6, 5.0, 15.4, np.nan]], dtype=np.float32)
    classes = classify(disparity, None, 0, 16)
    assert classes.tolist() == [[AT_BOUND, MATCHED, MATCHED, AT_BOUND, INVALID]]
    filled = np.array([[FILLED_OCCLUSION, MATCHED, MATCHED, MATCHED, INVALID]], np.uint8)
    assert classify(disparity, filled, 0, 16)[0, 0] == FILLED_OCCLUSION
    fractions = class_fractions(classes, np.ones_like(classes, dtype=bool))
    assert fractions == {"invalid": 0.2, "matched": 0.4, "filled_occlusion": 0.0,
                         "filled_mismatch": 0.0, "at_range_bound": 0.4}
