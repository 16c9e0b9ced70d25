"""Tests of the shared SIFT utilities (demtool.imaging.features)."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.errors import ParameterError, ProcessingError
from demtool.imaging import features
from tests.helpers.features import make_stereo_scene


@pytest.fixture(scope="module")
def scene():
    return make_stereo_scene(size=256)


def test_to_uint8_stretches_robustly_and_masks_nan():
    rng = np.random.default_rng(0)
    image = rng.uniform(1000, 3000, (50, 60)).astype(np.float32)
    image[0, 0] = 4095.0  # hot pixel must not compress the contrast
    image[10:20, 5:8] = np.nan
    image8, valid = features.to_uint8(image, percentiles=(1, 99))
    assert image8.dtype == np.uint8 and image8.shape == image.shape
    assert not valid[10:20, 5:8].any() and valid.sum() == image.size - 30
    assert image8[valid].min() == 0 and image8[valid].max() == 255
    # values between the percentiles keep their order
    inside = valid & (image > 1100) & (image < 2900)
    order = np.argsort(image[inside])
    assert np.all(np.diff(image8[inside][order].astype(int)) >= 0)
    # the fill of nodata is a mid grey, not an extreme
    assert 50 < image8[15, 6] < 205


def test_to_uint8_rejects_bad_input():
    with pytest.raises(ParameterError, match="2-D"):
        features.to_uint8(np.zeros((2, 3, 4)))
    with pytest.raises(ParameterError, match="percentiles"):
        features.to_uint8(np.zeros((5, 5)), percentiles=(90, 10))
    with pytest.raises(ParameterError, match="mask shape"):
        features.to_uint8(np.zeros((5, 5)), mask=np.ones((4, 5), bool))


def test_detect_sift_respects_mask_nan_offset_and_limit(scene):
    image = scene.left.copy()
    image[:, :100] = np.nan
    found = features.detect_sift(image, border_px=8)
    assert len(found) > 100
    assert found.points.dtype == np.float32 and found.descriptors.shape == (len(found), 128)
    assert found.points[:, 0].min() >= 100 + 8 - 1  # none near the nodata edge
    limited = features.detect_sift(scene.left, max_features=50)
    assert len(limited) == 50
    crop = features.detect_sift(scene.left[40:200, 30:220], offset=(30, 40))
    assert crop.points[:, 0].min() >= 30 and crop.points[:, 1].min() >= 40
    assert len(features.detect_sift(np.full((64, 64), np.nan, np.float32))) == 0
    assert len(features.detect_sift(np.full((64, 64), 7.0, np.float32))) == 0


def test_features_round_trip_through_arrays(scene):
    found = features.detect_sift(scene.left, max_features=30)
    again = features.Features.from_arrays(found.to_arrays())
    np.testing.assert_array_equal(again.points, found.points)
    np.testing.assert_array_equal(again.descriptors, found.descriptors)
    with pytest.raises(ValueError):
        features.Features.from_arrays({**found.to_arrays(), "sizes": np.zeros(3)})


def test_ratio_and_mutual_matching_on_known_pairs():
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 100, (200, 128)).astype(np.float32)
    shuffled = rng.permutation(200)
    other = base[shuffled] + rng.normal(0, 1.0, base.shape).astype(np.float32)
    pairs = features.match_descriptors(base, other, ratio=0.8)
    assert len(pairs) == 200
    np.testing.assert_array_equal(shuffled[pairs[:, 1]], pairs[:, 0])
    flann = features.match_descriptors(base, other, method="flann")
    assert len(flann) >= 190
    # a near-duplicate in b makes the match ambiguous: the ratio test drops it
    ambiguous = np.vstack([other, other[:1] + 0.01])
    kept = features.match_descriptors(base, ambiguous, ratio=0.8, mutual=False)
    assert shuffled[0] not in kept[:, 0]
    # mutual: two a descriptors wanting the same b keep at most one
    a = np.vstack([base[:5], base[:1] + 0.5])
    mutual = features.match_descriptors(a, base[:5], ratio=1.0, mutual=True)
    assert len(np.unique(mutual[:, 1])) == len(mutual) == 5
    assert features.match_descriptors(base[:0], other).shape == (0, 2)
    with pytest.raises(ParameterError, match="ratio"):
        features.match_descriptors(base, other, ratio=1.5)


def test_ransac_fundamental_recovers_true_epipolar_geometry(scene):
    a = features.detect_sift(scene.left)
    b = features.detect_sift(scene.right)
    pairs = features.match_descriptors(a.descriptors, b.descriptors)
    pa, pb = a.points[pairs[:, 0]], b.points[pairs[:, 1]]
    rng = np.random.default_rng(3)
    outliers = 60  # plus gross outliers that RANSAC must reject
    pb_noisy = np.vstack([pb, rng.uniform(0, 256, (outliers, 2))])
    pa_noisy = np.vstack([pa, rng.uniform(0, 256, (outliers, 2))])
    F, inliers = features.ransac_fundamental(pa_noisy, pb_noisy, threshold_px=1.0)
    assert inliers[:len(pa)].mean() > 0.9
    assert inliers[len(pa):].mean() < 0.1
    # true correspondences from the cameras satisfy F to a fraction of a pixel
    points = scene.terrain.surface_points(300, rng)
    ua, ub = scene.left_camera.project(points), scene.right_camera.project(points)
    inside = np.all((ua > 0) & (ua < 256) & (ub > 0) & (ub < 256), axis=1)
    assert np.median(features.sampson_distance(F, ua[inside], ub[inside])) < 0.1
    # the 8-point refit on the inliers agrees
    F8 = features.fit_fundamental(pa_noisy[inliers], pb_noisy[inliers])
    assert np.median(features.sampson_distance(F8, ua[inside], ub[inside])) < 0.1
    # reproducible
    F_again, inliers_again = features.ransac_fundamental(pa_noisy, pb_noisy, threshold_px=1.0)
    np.testing.assert_array_equal(inliers, inliers_again)


def test_ransac_fundamental_errors():
    points = np.random.default_rng(0).uniform(0, 100, (20, 2))
    with pytest.raises(ProcessingError, match="only 5 matches"):
        features.ransac_fundamental(points[:5], points[:5] + 3, what="a.tif/b.tif")
    with pytest.raises(ProcessingError, match="identical"):
        features.ransac_fundamental(points, points)
    with pytest.raises(ParameterError):
        features.ransac_fundamental(points, points + 1, threshold_px=0)
    with pytest.raises(ParameterError):
        features.ransac_fundamental(points, points + 1, method="lmeds")


def test_to_uint8_exact_keeps_8bit_data_rounds_and_zeroes_nodata():
    eight_bit = np.arange(256, dtype=np.float32).reshape(16, 16)
    kept, _ = features.to_uint8(eight_bit, exact=True)
    np.testing.assert_array_equal(kept, eight_bit.astype(np.uint8))
    twelve_bit = np.linspace(100, 4000, 400, dtype=np.float32).reshape(20, 20)
    twelve_bit[0, 0] = np.nan
    converted, valid = features.to_uint8(twelve_bit, percentiles=(0.1, 99.9), exact=True)
    assert converted.dtype == np.uint8 and converted[0, 0] == 0 and not valid[0, 0]
    assert converted.max() == 255 and converted.ravel()[1:].min() <= 1
    values = twelve_bit.ravel()[1:]
    low, high = np.percentile(values, (0.1, 99.9))
    expected = np.clip(np.round((values - low) / (high - low) * 255.0), 0, 255)
    np.testing.assert_array_equal(converted.ravel()[1:], expected.astype(np.uint8))


def test_detect_sift_keypoints_have_no_localisation_bias(scene):
    """Mirror test (issue 14): a keypoint at x in an image sits at W − 1 − x in its mirror
    image, so detected(x) − (W − 1 − detected_mirror) is twice the detector's bias.
    OpenCV's default upscaling of the first octave gave +0.25 px in x and y, which a
    bundle with ground control turns into a pointing bias of the whole block."""
    image = np.asarray(scene.left, dtype=np.float64)
    h, w = image.shape
    points = features.detect_sift(image).points.astype(np.float64)
    for axis in (0, 1):
        mirrored = np.ascontiguousarray(np.flip(image, axis=1 - axis))
        back = features.detect_sift(mirrored).points.astype(np.float64)
        back[:, axis] = (w if axis == 0 else h) - 1 - back[:, axis]
        dist = np.linalg.norm(points[:, None, :] - back[None, :, :], axis=2)
        nearest = dist.argmin(axis=1)
        same = dist[np.arange(len(points)), nearest] < 0.5
        assert same.sum() > 50
        twice_bias = points[same, axis] - back[nearest[same], axis]
        assert abs(np.median(twice_bias)) < 0.02  # 0.5 with the biased upscaling
