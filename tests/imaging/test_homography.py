"""Direct tests of demtool.imaging.homography: point mapping, inversion, disparity, warping."""

import numpy as np
import pytest

from demtool.imaging.homography import (
    apply_homography,
    disparity_to_correspondences,
    original_to_rectified,
    rectified_to_original,
    warp_to_rectified,
)

# a general projective map (shear, scale, translation and a perspective row)
H = np.array([[1.05, 0.02, 3.0], [-0.01, 0.98, -2.0], [1e-4, -2e-4, 1.0]])


def test_apply_homography_matches_the_definition_and_marks_infinity():
    points = np.array([[0.0, 0.0], [10.0, 5.0], [-3.5, 40.0]])
    mapped = apply_homography(H, points)
    for (x, y), (u, v) in zip(points, mapped, strict=True):
        w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
        assert u == pytest.approx((H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, abs=1e-12)
        assert v == pytest.approx((H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w, abs=1e-12)
    to_infinity = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    assert np.isnan(apply_homography(to_infinity, [[0.0, 7.0]])).all()


def test_rectified_to_original_inverts_original_to_rectified():
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 200, size=(50, 2))
    back = rectified_to_original(original_to_rectified(points, H), H)
    np.testing.assert_allclose(back, points, atol=1e-9)


def test_disparity_maps_to_the_right_original_points():
    disparity = np.full((4, 6), np.nan)
    disparity[1, 2] = 1.5
    disparity[3, 5] = -2.0
    identity = np.eye(3)
    left, right, pixels = disparity_to_correspondences(disparity, identity, identity)
    np.testing.assert_array_equal(pixels, [[1, 2], [3, 5]])
    np.testing.assert_allclose(left, [[2.0, 1.0], [5.0, 3.0]])
    np.testing.assert_allclose(right, [[0.5, 1.0], [7.0, 3.0]])  # x_right = x_left - d
    shifted = np.array([[1.0, 0, 10.0], [0, 1.0, 20.0], [0, 0, 1.0]])  # rectified = original + t
    left, right, _ = disparity_to_correspondences(disparity, shifted, shifted)
    np.testing.assert_allclose(left, [[-8.0, -19.0], [-5.0, -17.0]])


def test_warp_is_exact_for_a_linear_ramp_and_nan_outside():
    rows, cols = np.mgrid[0:40, 0:50].astype(np.float32)
    image = 2.0 * cols + 0.5 * rows
    translate = np.array([[1.0, 0, 4.0], [0, 1.0, -3.0], [0, 0, 1.0]])  # rectified = original + t
    warped = warp_to_rectified(image, translate, (50, 40))
    assert warped.shape == (40, 50) and warped.dtype == np.float32
    r, c = np.mgrid[0:40, 0:50]
    expected = 2.0 * (c - 4.0) + 0.5 * (r + 3.0)
    inside = (c - 4.0 >= 0) & (r + 3.0 <= 39)
    np.testing.assert_allclose(warped[inside], expected[inside], atol=1e-4)
    assert np.isnan(warped[~inside]).all()
    half = np.array([[0.5, 0, 0], [0, 0.5, 0], [0, 0, 1.0]])  # shrink by 2: bilinear at 2x
    small = warp_to_rectified(image, half, (25, 20))
    np.testing.assert_allclose(small, image[::2, ::2], atol=1e-4)
