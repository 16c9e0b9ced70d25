"""Footprints, footprint overlap (spatial pairs) and SIFT tracks of a sensor block."""

from __future__ import annotations

import numpy as np

from demtool.bundle import ties
from demtool.sensors import FrameSensor
from tests.bundle import frames


def test_clip_of_squares_has_the_known_area():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    assert np.isclose(ties._area(ties._clip(square, square + [0.5, 0.25])), 0.5 * 0.75)
    assert ties._area(ties._clip(square, square + [2.0, 0.0])) == 0.0
    hull = ties._convex_hull(np.vstack([square, [[0.5, 0.5]]]))
    assert len(hull) == 4 and np.isclose(ties._area(hull), 1.0)


def test_footprint_lies_on_the_body():
    model = frames.true_models(size=300)[0]
    border = ties.footprint(model)
    assert len(border) == 32
    assert np.allclose(np.linalg.norm(border, axis=1), frames.RADIUS, atol=1e-3)
    line, sample = model.ground_to_image(border)
    on_edge = np.minimum.reduce([line, sample, model.lines - line, model.samples - sample])
    assert np.all(np.abs(on_edge) < 1e-6)


def test_overlapping_pairs():
    models = frames.true_models(size=300)
    pairs, overlap = ties.overlapping_pairs(models)
    assert len(pairs) == 15 and np.all(overlap[np.triu_indices(6, 1)] > 0.3)
    m = models[0]
    assert np.isclose(ties.overlapping_pairs([m, m])[1][0, 1], 1.0)
    # moved 60 km east: no footprint in common
    east = np.cross([0.0, 0.0, 1.0], m.position)
    east /= np.linalg.norm(east)
    far = FrameSensor(position=m.position + 60e3 * east, rotation=m.rotation,
                      focal_length=m.focal_length, detector=m.detector, lines=m.lines,
                      samples=m.samples, radii=m.radii)
    pairs, overlap = ties.overlapping_pairs([m, models[1], far])
    assert pairs == [(0, 1)] and overlap[0, 2] == 0.0 and overlap[1, 2] == 0.0


def test_image_pairs_orders():
    assert len(ties.image_pairs(5, "exhaustive")) == 10
    sequential = ties.image_pairs(15, "sequential")
    assert (0, 10) in sequential and (0, 11) not in sequential


def test_tie_points_are_tracks_across_images():
    truth = frames.true_models(count=4, size=240)
    images = [frames.render(m) for m in truth]
    obs, report = ties.tie_points(images, ties.image_pairs(4, "exhaustive"),
                                  max_features=1500)
    assert obs.point_count > 200 and min(report["pairs"].values()) > 50
    counts = np.bincount(obs.point)
    assert counts.min() >= 2 and counts.max() <= 4
    assert np.mean(counts) > 2.2  # multi-view tracks, not only pairs
    # the matches are right: each track's rays meet near one point of the terrain
    from demtool.bundle.priors import triangulate

    points, miss = triangulate(truth, obs)
    assert np.median(miss) < 30.0  # pixels of 100 m, 40° field of view


def test_default_keypoints_grow_with_the_image_within_bounds():
    assert ties.features_per_image((256, 256)) == ties.MIN_FEATURES
    assert ties.features_per_image((1500, 2000)) == 1500 * 2000 // ties.PIXELS_PER_FEATURE
    assert ties.features_per_image((2048, 2048)) == 65536
    assert ties.features_per_image((5000, 20000)) == ties.MAX_FEATURES


def test_tie_points_ask_each_image_for_its_default_keypoints(monkeypatch):
    from demtool.imaging import features

    asked = []
    real = features.detect_sift

    def spy(image, **kwargs):
        asked.append((np.shape(image), kwargs["max_features"]))
        return real(image, **kwargs)

    monkeypatch.setattr(features, "detect_sift", spy)
    images = [np.random.default_rng(0).random((120, 100)), np.zeros((1500, 2000))]
    ties.tie_points(images, [(0, 1)], refine=False)
    assert asked == [((120, 100), 8192), ((1500, 2000), 46875)]
    asked.clear()
    ties.tie_points(images, [(0, 1)], max_features=500, refine=False)
    assert [k for _, k in asked] == [500, 500]


def test_bundle_help_states_the_default_density():
    """``--max-features``'s help writes the rule out (params stays free of the core's
    imports, which ``--help`` would pay for); it must say what the core does."""
    import dataclasses

    from demtool.bundle.params import BundleParams

    field = next(f for f in dataclasses.fields(BundleParams) if f.name == "max_features")
    text = field.metadata["help"]
    assert f"one per {ties.PIXELS_PER_FEATURE} pixels" in text
    assert f"{ties.MIN_FEATURES} to {ties.MAX_FEATURES}" in text
