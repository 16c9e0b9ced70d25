"""Pair choice from measured geometry: each limit, the sun difference, the ranking."""

import pytest

from demtool.pairs.core import pair_verdicts, select_pairs, sun_difference_deg


def camera(name, az=225.0, el=30.0):
    return {"name": name, "sun_azimuth_deg": az, "sun_elevation_deg": el}


def pair(first, second, overlap=0.9, convergence=20.0, bh=0.4):
    return {"first": first, "second": second, "overlap_fraction_first": 1.0,
            "overlap_fraction_second": overlap, "convergence_deg": convergence,
            "base_to_height": bh}


def test_sun_difference_is_the_angle_between_the_directions():
    assert sun_difference_deg(camera("a", 90, 30), camera("b", 90, 30)) == pytest.approx(0)
    assert sun_difference_deg(camera("a", 90, 0), camera("b", 180, 0)) == pytest.approx(90)
    assert sun_difference_deg(camera("a", 0, 20), camera("b", 0, 50)) == pytest.approx(30)
    assert sun_difference_deg({"name": "a"}, camera("b")) is None


def test_each_limit_rejects_with_its_reason_and_the_best_come_first():
    cameras = [camera("a"), camera("b"), camera("c"), camera("d", az=100)]
    pairs = [pair("a", "b", bh=0.5), pair("a", "c", overlap=0.3), pair("b", "c", convergence=5),
             pair("a", "d"), pair("b", "d", bh=0.1, convergence=15), pair("c", "b", bh=0.3)]
    verdicts = pair_verdicts(cameras, pairs)
    reasons = {(v["first"], v["second"]): v["reasons"] for v in verdicts}
    assert reasons[("a", "b")] == [] and reasons[("c", "b")] == []
    assert reasons[("a", "c")] == ["overlap 30% < 50%"]
    assert reasons[("b", "c")] == ["convergence 5.0° outside 10–60°"]
    assert reasons[("a", "d")][0].startswith("sun directions")
    assert reasons[("b", "d")][0] == "B/H 0.10 outside 0.2–1"
    chosen = select_pairs(verdicts)
    assert [(v["first"], v["second"]) for v in chosen] == [("a", "b"), ("c", "b")]
    assert len(select_pairs(verdicts, max_pairs=1)) == 1
    # widening a limit lets a pair in
    wide = pair_verdicts(cameras, pairs, max_sun_difference=180)
    assert not [v for v in wide if v["second"] == "d" and v["first"] == "a"][0]["reasons"]
