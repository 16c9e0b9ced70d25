"""Cost "auto" near depth edges: the pixel census cross-checked against a matching from
the right image (issue 26)."""

from __future__ import annotations

import numpy as np

from demtool.sgm import auto as rules
from demtool.sgm import sgm
from demtool.sgm.auto import at_depth_edges, cross_check, depth_edge_zone, mirrored
from tests.helpers.sgm import error_rates, occlusion_pair


def _box_maps():
    """Left and right disparity maps of a box (14 px) before a background (4 px), one
    row of 40 px: the box covers left columns 20 … 29, the right view hides left
    columns 10 … 19 (no match there)."""
    width = 40
    left = np.full((1, width), 4.0, dtype=np.float32)
    left[0, 20:30] = 14.0
    right = np.full((1, width), 4.0, dtype=np.float32)
    right[0, 6:16] = 14.0  # right pixels x_r show the box where x_r + 14 is in it
    return left, right


def test_cross_check_keeps_the_consistent_pixels_and_marks_the_occluded():
    left, right = _box_maps()
    confidence = np.full(left.shape, 0.5, dtype=np.float32)
    disparity, kept, occluded = cross_check(left, confidence, right)
    hidden = np.zeros(left.shape, dtype=bool)
    hidden[0, 10:20] = True  # their background match x − 4 shows the box in the right view
    assert np.array_equal(np.isnan(disparity), hidden | (np.arange(40) < 4)[None, :])
    assert np.array_equal(occluded, hidden)
    assert np.array_equal(np.isnan(kept), np.isnan(disparity))
    # a wrong disparity whose match shows the background is a mismatch, not an occlusion
    wrong = left.copy()
    wrong[0, 35] = 9.0
    disparity, _, occluded = cross_check(wrong, confidence, right)
    assert np.isnan(disparity[0, 35]) and not occluded[0, 35]
    # within the threshold (sub-pixel values) the pixel stays
    close = left.copy()
    close[0, 35] = 4.8
    assert cross_check(close, confidence, right)[0][0, 35] == np.float32(4.8)


def test_the_depth_edge_zone_is_where_disparities_jump_not_where_they_slope():
    cols = np.mgrid[0:40, 0:60][1]
    slope = (0.05 * cols).astype(np.float32)  # 3 px over the row: no edge
    assert not depth_edge_zone(slope, radius=5, jump=2.0).any()
    step = slope + 10.0 * (cols >= 30)
    step[:, 28:30] = np.nan  # an occlusion beside the step: ignored, not an edge itself
    zone = depth_edge_zone(step, radius=5, jump=6.0)
    # the 11-px windows that hold a finite pixel on either side: centres 25 … 32
    assert zone[:, 25:33].all() and not zone[:, :25].any() and not zone[:, 33:].any()


def test_mirrored_swaps_and_flips_the_images():
    images = {"left": np.arange(6.0).reshape(2, 3), "right": -np.arange(6.0).reshape(2, 3),
              "left_valid": np.ones((2, 3), dtype=bool),
              "right_valid": np.array([[True, False, True], [True, True, True]])}
    out = mirrored(images)
    assert np.array_equal(out["left"], images["right"][:, ::-1])
    assert np.array_equal(out["right"], images["left"][:, ::-1])
    assert np.array_equal(out["left_valid"], images["right_valid"][:, ::-1])
    zone = np.array([[True, False, False]])
    base = (np.zeros((1, 3)), np.ones((1, 3)), np.zeros((1, 3), dtype=bool))
    sharp = (np.full((1, 3), 7.0), np.full((1, 3), 2.0), np.ones((1, 3), dtype=bool))
    merged = at_depth_edges(zone, base, sharp)
    assert merged[0].tolist() == [[7.0, 0.0, 0.0]] and merged[2].tolist() == [[True, False, False]]


def test_auto_takes_the_cross_checked_pixel_census_at_a_boxes_borders(monkeypatch):
    left, right, truth, _ = occlusion_pair(noise=3.0)
    # the path under test: a noisy pair where HMI and windowed census agree
    monkeypatch.setattr(rules, "FINE_NOISE_MAX", -1.0)
    monkeypatch.setattr(rules, "prefer_census", lambda *args: "")
    monkeypatch.setattr(rules, "prefer_gradient", lambda *args: "")
    scored = np.zeros(truth.shape, dtype=bool)
    scored[4:-4, 24:-4] = True
    edges = sgm(left, right, min_disparity=0, num_disparities=24, workers=1)
    assert edges.fractions["cost_used"] == "hmi+census"
    assert 0.2 < edges.fractions["edge_census"] < 0.5  # the box's border, 12 px wide
    monkeypatch.setattr(rules.depth_edge_zone, "__defaults__",
                        (rules.EDGE_ZONE_RADIUS, np.inf))  # no zone: HMI confirmed alone
    plain = sgm(left, right, min_disparity=0, num_disparities=24, workers=1)
    assert "edge_census" not in plain.fractions
    bad_edges = error_rates(edges.disparity, truth, scored)["bad1"]
    bad_plain = error_rates(plain.disparity, truth, scored)["bad1"]
    assert bad_edges < 0.7 * bad_plain, (bad_edges, bad_plain)


def test_the_edge_census_is_skipped_where_the_pixel_census_replaces_all_its_pixels(
        monkeypatch):
    # a low-noise box: the pixel census near depth discontinuities (here widened to 20 px,
    # so that it covers every depth edge) replaces the windowed choice there, so the
    # windowed choice's edge census (two passes) would be thrown away: skipped, and the
    # result is exactly the one with it
    left, right, _, _ = occlusion_pair(noise=1.0, box=(30, 66, 56, 76))
    monkeypatch.setattr(rules, "prefer_census", lambda *args: "")
    monkeypatch.setattr(rules, "prefer_gradient", lambda *args: "")
    monkeypatch.setattr(rules.discontinuity_zone, "__defaults__", (20, rules.FINE_EDGE_JUMP))
    skipped = sgm(left, right, min_disparity=0, num_disparities=24, workers=1)
    always = rules.windowed_choice
    monkeypatch.setattr(rules, "windowed_choice",
                        lambda *args, replaced=None, **kwargs: always(*args, **kwargs))
    full = sgm(left, right, min_disparity=0, num_disparities=24, workers=1)
    assert skipped.fractions["cost_used"] == full.fractions["cost_used"] == "census+hmi+census"
    assert len(skipped.levels) == len(full.levels) - 2  # the edge census's two passes
    assert np.array_equal(skipped.disparity, full.disparity, equal_nan=True)
    assert np.array_equal(skipped.confidence, full.confidence, equal_nan=True)
    assert skipped.fractions == full.fractions
