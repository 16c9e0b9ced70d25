"""Tests of uncalibrated rectification (demtool.rectify.core, demtool rectify)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from demtool.errors import ProcessingError
from demtool.imaging.homography import (
    apply_homography,
    disparity_to_correspondences,
    rectified_to_original,
    warp_to_rectified,
)
from demtool.rectify import core as rectify
from tests.conftest import STEREO_SCENE_SIZE as SIZE


@pytest.fixture(scope="module")
def result(stereo_scene):
    return rectify.rectify_pair(stereo_scene.left, stereo_scene.right, what="L / R")


def _truth_points(stereo_scene, count=600, seed=5):
    """Surface points seen by both cameras and their pixel coordinates."""
    points = stereo_scene.terrain.surface_points(count, np.random.default_rng(seed))
    ul, ur = stereo_scene.left_camera.project(points), stereo_scene.right_camera.project(points)
    inside = np.all((ul > 1) & (ul < SIZE - 2) & (ur > 1) & (ur < SIZE - 2), axis=1)
    return points[inside], ul[inside], ur[inside]


def test_rectified_truth_points_share_rows(stereo_scene, result):
    assert result.rms_vertical_residual < 0.5
    assert np.all(np.abs(result.vertical_residuals) <= 1.0)
    assert len(result.points_left) > 200 and result.n_ransac_inliers <= result.n_matches
    points, ul, ur = _truth_points(stereo_scene)
    left_rect = apply_homography(result.H_left, ul)
    right_rect = apply_homography(result.H_right, ur)
    row_error = left_rect[:, 1] - right_rect[:, 1]
    assert np.max(np.abs(row_error)) < 0.5
    assert np.sqrt(np.mean(row_error**2)) < 0.2
    # the disparity range brackets every true disparity, and disparity follows height
    disparity = left_rect[:, 0] - right_rect[:, 0]
    low, high = result.disparity_range
    assert low < disparity.min() and disparity.max() < high
    assert high - low < 3 * (disparity.max() - disparity.min()) + 40
    assert np.corrcoef(disparity, points[:, 2])[0, 1] > 0.8  # left camera is west: d grows up
    assert abs(np.mean(result.disparities)) < 1e-6  # translation centres the control points


def test_rectifies_the_synthetic_scene_pair(small_scene):
    """The synth stage's target/partner pair: truth rows agree, the range brackets truth."""
    from demtool.synth import truth_disparity

    left = small_scene.images[small_scene.target]
    right = small_scene.images[small_scene.partner]
    result = rectify.rectify_pair(left, right, what="target / partner")
    assert result.rms_vertical_residual < 0.5
    width, height = result.size_rect
    truth = truth_disparity(small_scene, result.H_left, result.H_right, (height, width))
    from demtool.synth import rectified_correspondence

    match = rectified_correspondence(small_scene, result.H_left, result.H_right, (height, width))
    rows = np.arange(height, dtype=float)[:, None] - match.y_right
    visible = truth.visible
    assert visible.sum() > 0.5 * left.size
    assert np.nanmax(np.abs(rows[visible])) < 0.5
    low, high = result.disparity_range
    assert low < np.nanmin(truth.disparity[visible])
    assert np.nanmax(truth.disparity[visible]) < high


def test_rectification_keeps_orientation_and_resolution(result):
    for H, size in ((result.H_left, result.size_left), (result.H_right, result.size_right)):
        centre = (size - 1) / 2.0
        ends = apply_homography(H, np.array([centre, centre + [10, 0], centre + [0, 10]]))
        x_axis, y_axis = ends[1] - ends[0], ends[2] - ends[0]
        assert x_axis[0] > 0 and y_axis[1] > 0  # no mirror, no half-turn
        assert x_axis[0] * y_axis[1] - x_axis[1] * y_axis[0] > 0
        assert 0.7 < np.linalg.norm(x_axis) / 10 < 1.4  # resolution roughly kept
        assert abs(np.dot(x_axis, y_axis)) / 100 < 0.15  # shear keeps pixels nearly square
        corners = apply_homography(H, np.array([[0, 0], [size[0] - 1, size[1] - 1]]))
        assert np.all(corners >= -1e-6) and np.all(corners <= result.size_rect - 1 + 1e-6)
    assert np.prod(result.size_rect) < 3 * SIZE * SIZE


def test_loop_zhang_shear_undoes_a_shear():
    H = np.array([[1.2, 0.35, 4.0], [0.0, 1.0, -2.0], [0.0, 0.0, 1.0]])
    S = rectify.loop_zhang_shear(H, np.array([200, 100]))
    mid = apply_homography(S @ H, np.array([[0, 49.5], [199, 49.5], [99.5, 0], [99.5, 99]]))
    horizontal, vertical = mid[1] - mid[0], mid[3] - mid[2]
    assert abs(np.dot(horizontal, vertical)) < 1e-6 * np.linalg.norm(horizontal) ** 2
    np.testing.assert_allclose(np.linalg.norm(horizontal) / np.linalg.norm(vertical), 199 / 99)
    assert S[1, 1] == 1 and S[1, 0] == 0  # rows untouched


def test_identical_images_are_refused(stereo_scene):
    with pytest.raises(ProcessingError, match=r"L / L.*(coincide|identical)"):
        rectify.rectify_pair(stereo_scene.left, stereo_scene.left, what="L / L")


def test_pure_rotation_is_refused(stereo_scene):
    angle = np.deg2rad(8)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                         [0, 0, 1]])
    centre = np.array([[1, 0, SIZE / 2], [0, 1, SIZE / 2], [0, 0, 1]])
    H = centre @ rotation @ np.linalg.inv(centre)
    H[2, :2] = [2e-4, -1e-4]  # plus some perspective: still a homography
    rotated = cv2.warpPerspective(stereo_scene.left, H, (SIZE, SIZE), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    with pytest.raises(ProcessingError, match="no parallax"):
        rectify.rectify_pair(stereo_scene.left, rotated, what="L / rotated")


def test_noise_pair_has_too_few_matches():
    rng = np.random.default_rng(0)
    a = cv2.GaussianBlur(rng.normal(0, 1, (160, 160)).astype(np.float32), (0, 0), 1.5)
    b = cv2.GaussianBlur(rng.normal(0, 1, (160, 160)).astype(np.float32), (0, 0), 1.5)
    with pytest.raises(ProcessingError, match=r"noise / noise: only \d+ SIFT matches.*at least 30"):
        rectify.rectify_pair(a, b, min_matches=30, what="noise / noise")


def test_images_of_different_sizes(stereo_scene):
    right = stereo_scene.right[10:230, 5:250]
    result = rectify.rectify_pair(stereo_scene.left, right, what="L / cropped R")
    assert result.size_right.tolist() == [245, 220]
    assert result.rms_vertical_residual < 0.5
    _, ul, ur = _truth_points(stereo_scene)
    ur = ur - [5, 10]
    inside = np.all((ur > 1) & (ur < [243, 218]), axis=1)
    rows = (apply_homography(result.H_left, ul[inside])[:, 1]
            - apply_homography(result.H_right, ur[inside])[:, 1])
    assert np.max(np.abs(rows)) < 0.5


def test_warp_and_inverse_mapping():
    image = np.arange(40 * 50, dtype=np.float32).reshape(40, 50)
    H = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, -2.0], [0.0, 0.0, 1.0]])
    warped = warp_to_rectified(image, H, (60, 40))
    np.testing.assert_allclose(warped[0:38, 3:53], image[2:40, 0:50])
    assert np.isnan(warped[:, :3]).all() and np.isnan(warped[38:, :]).all()
    half = warp_to_rectified(image, np.array([[1, 0, 0.5], [0, 1, 0], [0, 0, 1.0]]), (50, 40))
    np.testing.assert_allclose(half[5, 1:50], 0.5 * (image[5, :49] + image[5, 1:]))
    holes = image.copy()
    holes[10, 10] = np.nan
    assert np.isnan(warp_to_rectified(holes, H, (60, 40))[8, 13])
    # disparity → original correspondences
    H_left = np.array([[1.0, 0.1, 5.0], [0.0, 1.0, 2.0], [1e-4, 0.0, 1.0]])
    H_right = np.array([[0.9, 0.0, -3.0], [0.05, 1.0, 2.0], [0.0, 2e-4, 1.0]])
    disparity = np.full((30, 40), np.nan, np.float32)
    disparity[5:20, 10:30] = 4.25
    left, right, pixels = disparity_to_correspondences(disparity, H_left, H_right)
    assert len(left) == 15 * 20
    back_left = apply_homography(H_left, left)
    back_right = apply_homography(H_right, right)
    np.testing.assert_allclose(back_left, pixels[:, ::-1], atol=1e-9)
    np.testing.assert_allclose(back_left[:, 0] - back_right[:, 0], 4.25, atol=1e-9)
    np.testing.assert_allclose(back_left[:, 1], back_right[:, 1], atol=1e-9)
    np.testing.assert_allclose(rectified_to_original(back_left, H_left), left, atol=1e-9)


# ------------------------------------------------------------ disparity range, GRIC (issue 13)


def test_robust_disparity_range_ignores_gross_mismatches():
    rng = np.random.default_rng(3)
    true = rng.uniform(-10.0, 30.0, 2000)
    gross = rng.uniform(-400.0, 400.0, 20)  # 1 % anywhere in ±400 px
    low, high = rectify.robust_disparity_range(np.concatenate([true, gross]))
    span = true.max() - true.min()
    # covers the true range and stays within it + 10 % of its span on each side
    assert low <= true.min() and high >= true.max() - 0.5
    assert low >= true.min() - 0.1 * span and high <= true.max() + 0.1 * span
    # the minimum and maximum would have searched over ten times as many disparities
    assert (gross.max() - gross.min()) > 10 * (high - low)
    with pytest.raises(ProcessingError, match="no control point"):
        rectify.robust_disparity_range(np.array([np.nan]))


def test_gross_mismatches_on_epipolar_lines_keep_the_range(stereo_scene, result):
    _, ul, ur = _truth_points(stereo_scene, count=1500, seed=9)
    rng = np.random.default_rng(4)
    bad = rng.choice(len(ul), size=max(3, len(ul) // 100), replace=False)
    # move the right point along its epipolar line by 100 … 400 px: F still holds
    lines = (np.column_stack([ul, np.ones(len(ul))]) @ result.F.T)[bad]
    direction = np.column_stack([lines[:, 1], -lines[:, 0]])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    shifted = ur.copy()
    shifted[bad] += direction * (rng.uniform(100, 400, len(bad)) * rng.choice([-1, 1],
                                                                              len(bad)))[:, None]
    size = np.array([SIZE, SIZE])
    corrupted = rectify.rectify_matches(ul, shifted, size, size, what="corrupted")
    good = np.setdiff1d(np.arange(len(ul)), bad)
    true = (apply_homography(corrupted.H_left, ul[good])[:, 0]
            - apply_homography(corrupted.H_right, ur[good])[:, 0])
    span = true.max() - true.min()
    low, high = corrupted.disparity_range
    slack = max(2.0, 0.1 * span)  # the least margin, or 10 % of the span
    assert true.min() - slack - 0.5 <= low <= np.percentile(true, 1)
    assert np.percentile(true, 99) <= high <= true.max() + slack + 0.5


def _plane_and_parallax(parallax_fraction, parallax_px, noise_px=0.25, n=400, seed=0):
    """Matches induced by a plane (homography H) plus horizontal parallax on a fraction.

    With the epipole at infinity along x, x_right = H x_left + (ρ, 0) is consistent
    with F = [e']× H for any ρ (plane + parallax).
    """
    rng = np.random.default_rng(seed)
    left = rng.uniform(20, 480, (n, 2))
    H = np.array([[1.02, 0.01, 12.0], [0.004, 0.99, -3.0], [1e-5, -2e-5, 1.0]])
    right = apply_homography(H, left)
    off_plane = rng.random(n) < parallax_fraction
    right[off_plane, 0] += rng.uniform(-parallax_px, parallax_px, off_plane.sum())
    right += rng.normal(0, noise_px, right.shape)
    left += rng.normal(0, noise_px, left.shape)
    return left, right


def test_a_dominant_plane_with_strong_parallax_is_not_refused():
    left, right = _plane_and_parallax(0.1, 25.0)  # RMS parallax ~4 px, σ ~0.26 px
    import cv2 as _cv2

    H, _ = _cv2.findHomography(left, right, _cv2.RANSAC, 1.0)
    F, inliers = rectify.features.ransac_fundamental(left, right, threshold_px=1.0, seed=0,
                                                     what="rover")
    difference, sigma = rectify.gric_difference(F, H, left[inliers], right[inliers])
    assert difference <= 0  # GRIC alone prefers the homography here ...
    out = rectify.rectify_matches(left, right, (500, 500), (500, 500), what="rover")
    assert out.rms_vertical_residual < 0.5  # ... but the pair is rectified
    assert np.ptp(out.disparities) > 20  # the parallax is there to match


def test_a_flat_pair_is_refused_with_what_was_seen():
    left, right = _plane_and_parallax(0.0, 0.0)
    with pytest.raises(ProcessingError, match=r"flat: .*GRIC\(H\) − GRIC\(F\) = -?\d.*RMS "
                                              r"residual parallax \d+\.\d+ px.*σ of \d"):
        rectify.rectify_matches(left, right, (500, 500), (500, 500), what="flat")


# ------------------------------------------------- turns and single-match ranges (issue 12)


def _parallax_along(angle_deg, parallax_px, noise_px=0.05, n=400, seed=1, fraction=1.0,
                    aligned=False):
    """Matches of a plane (homography) plus parallax along the direction ``angle_deg``.

    The right epipole is at infinity in that direction, so F = [e']× H and Hartley's
    rectification turns the images by ``angle_deg`` (folded to ±90°).  ``aligned``: the
    plane maps the images onto each other (H = identity, two orthoimages of one grid).
    """
    rng = np.random.default_rng(seed)
    left = rng.uniform(20, 480, (n, 2))
    H = np.eye(3) if aligned else np.array([[1.01, 0.005, 6.0], [-0.004, 0.995, 4.0],
                                             [0.0, 0.0, 1.0]])
    right = apply_homography(H, left)
    direction = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    moved = rng.random(n) < fraction
    right[moved] += rng.uniform(-parallax_px, parallax_px, moved.sum())[:, None] * direction
    right += rng.normal(0, noise_px, right.shape)
    left += rng.normal(0, noise_px, left.shape)
    return left, right


def test_rotation_at_centre_measures_a_known_turn():
    for angle in (0.0, 30.0, -90.0, 135.0):
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        H = np.array([[2 * c, -2 * s, 5.0], [2 * s, 2 * c, -7.0], [0.0, 0.0, 1.0]])
        assert rectify.rotation_at_centre(H, np.array([500, 300])) == pytest.approx(angle,
                                                                                     abs=1e-9)
    # a projective map: the rotation of the polar decomposition of the local Jacobian
    P = np.array([[1.0, 0.2, 0.0], [-0.1, 1.1, 0.0], [1e-3, 4e-4, 1.0]])
    centre, step = np.array([249.5, 149.5]), 1e-5
    ends = apply_homography(P, np.array([centre, centre + [step, 0], centre + [0, step]]))
    J = np.column_stack([ends[1] - ends[0], ends[2] - ends[0]]) / step
    U, _, Vt = np.linalg.svd(J)
    R = U @ Vt
    polar = np.degrees(np.arctan2(R[1, 0], R[0, 0]))
    assert abs(polar) > 3  # a real turn to measure
    assert rectify.rotation_at_centre(P, np.array([500, 300])) == pytest.approx(polar, abs=1e-3)


def test_a_vertical_baseline_is_turned_by_90_degrees():
    """Parallax along the columns (20 px RMS, ~0.3 across): the 90° turn is the geometry."""
    left, right = _parallax_along(90.0, 35.0)
    out = rectify.rectify_matches(left, right, (500, 500), (500, 500), what="vertical")
    turn = rectify.rotation_at_centre(out.H_left, out.size_left)
    assert abs(abs(turn) - 90.0) < 2.0
    assert out.rms_vertical_residual < 0.2
    assert np.ptp(out.disparities) > 50  # the parallax became disparity
    along, across = rectify.epipolar_parallax(out.F, out.points_left, out.points_right)
    assert along > 15 and across < 0.05 * along


def test_an_oblique_baseline_is_turned_by_its_angle():
    left, right = _parallax_along(35.0, 30.0)
    out = rectify.rectify_matches(left, right, (500, 500), (500, 500), what="oblique")
    # turning the parallax direction (35°) onto the x axis is a turn of −35°
    assert rectify.rotation_at_centre(out.H_right, out.size_right) == pytest.approx(-35, abs=2)


def test_aligned_images_are_not_turned():
    """Aligned images (sub-pixel parallax along the columns): the 90° turn is refused."""
    left, right = _parallax_along(90.0, 0.8, aligned=True)  # 0.46 px RMS, 0.05 px noise
    size = np.array([500, 500])
    assert rectify.alignment_shift(left, right, size) < 0.5
    F, inliers = rectify.features.ransac_fundamental(left, right, threshold_px=1.0, seed=0,
                                                     what="aligned")
    H_left, H_right = rectify.hartley_homographies(F, left[inliers], right[inliers], size, size)
    assert abs(rectify.rotation_at_centre(H_right, size)) > 80  # it would turn
    with pytest.raises(ProcessingError, match=r"aligned: the rectification would turn the "
                                              r"images by -?\d+° .*already aligned .*0\.\d\d "
                                              r"px RMS of parallax.*mapproject"):
        rectify.rectify_matches(left, right, (500, 500), (500, 500), what="aligned")
    # the same sub-pixel parallax along the rows needs no turn and is rectified
    left, right = _parallax_along(0.0, 0.8, aligned=True)
    out = rectify.rectify_matches(left, right, (500, 500), (500, 500), what="rows")
    assert abs(rectify.rotation_at_centre(out.H_left, out.size_left)) < 2
    # and a raw pair (views 8 px apart) with that parallax along the columns is turned:
    # a weak but genuine stereo pair, not two orthoimages
    left, right = _parallax_along(90.0, 0.8)
    out = rectify.rectify_matches(left, right, (500, 500), (500, 500), what="raw")
    assert abs(abs(rectify.rotation_at_centre(out.H_left, out.size_left)) - 90) < 3
    assert rectify.alignment_shift(left, right, size) > rectify.ALIGNED_SHIFT_PX


def test_a_turn_against_the_parallax_is_refused():
    """An F whose epipolar lines (rows) cross the matches' parallax (columns): refused."""
    left, right = _parallax_along(90.0, 3.0, noise_px=0.3, seed=4)
    F_rows = np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0.0]])  # [e]x, e = (1, 0, 0)
    along, across = rectify.epipolar_parallax(F_rows, left, right)
    assert along < 0.6 and across > 1.5  # the parallax is across F's lines
    quarter = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])  # a 90° turn
    size = np.array([500, 500])
    with pytest.raises(ProcessingError, match=r"iso: .*turn the images by 90° and 90°.*"
                                              r"does not show that baseline"):
        rectify.check_rotation(quarter, quarter, F_rows, left, right, size, size,
                               max_rotation_deg=10.0, what="iso")
    # a turn within the limit is not questioned, whatever the parallax
    small = np.array([[np.cos(0.1), -np.sin(0.1), 0], [np.sin(0.1), np.cos(0.1), 0], [0, 0, 1]])
    assert rectify.check_rotation(small, small, F_rows, left, right, size, size,
                                  max_rotation_deg=10.0) == \
        pytest.approx(np.degrees(0.1))


def test_one_match_does_not_set_the_disparity_range():
    """Issue 13's percentiles alone let one match set the range of a small set of points."""
    rng = np.random.default_rng(8)
    true = rng.uniform(-10.0, 30.0, 40)
    with_one = np.append(true, 376.0)
    low, high = np.percentile(with_one, rectify.DISPARITY_PERCENTILES)
    assert high > 150  # the 99th percentile of 41 points is pulled 40 % of the way to 376
    low, high = rectify.robust_disparity_range(with_one)
    assert low <= np.sort(true)[2]
    assert np.sort(true)[-3] <= high <= true.max() + 0.1 * np.ptp(true) + 1e-9
    assert low >= true.min() - 0.1 * np.ptp(true) - 1e-9
    # with 2000 points the percentiles already hold it (issue 13), and still do
    many = np.append(rng.uniform(-10.0, 30.0, 2000), [376.0, -300.0])
    low, high = rectify.robust_disparity_range(many)
    assert -15 < low < -9 and 29 < high < 35
    with pytest.raises(ProcessingError, match="pair: only 5 control point.*needs 3.*"
                                              "--disparity-range"):
        rectify.robust_disparity_range(np.arange(5.0), what="pair")


def test_a_single_match_on_its_epipolar_line_does_not_set_the_range():
    left, right = _parallax_along(0.0, 10.0, n=40, seed=6)
    right[7, 0] += 300.0  # on its epipolar line (a row): passes RANSAC and the row test
    out = rectify.rectify_matches(left, right, (500, 500), (500, 500), what="one")
    assert len(out.points_left) == 40  # the match is kept as a control point ...
    d = np.sort(out.disparities)
    low, high = out.disparity_range
    assert high < d[-2] + 0.1 * (d[-2] - d[0]) + 2.5  # ... but does not set the range
    assert low <= d[2] and high >= d[-3]


def test_the_synthetic_column_baseline_pair_is_turned_and_rectified(small_scene):
    """view_00/view_03 of the small scene (camera 490 m along −y at 1000 m, B/H 0.5):
    a genuine −72° turn with sub-pixel-RMS parallax on images that are not aligned."""
    from demtool.synth import target_points

    left = small_scene.images[small_scene.target]
    right = small_scene.images["view_03"]
    result = rectify.rectify_pair(left, right, what="view_00 / view_03")
    assert -80 < rectify.rotation_at_centre(result.H_left, result.size_left) < -60
    along, across = rectify.epipolar_parallax(result.F, result.points_left,
                                              result.points_right)
    assert along < rectify.MIN_TURN_PARALLAX_PX and along > 3 * across
    assert rectify.alignment_shift(result.points_left, result.points_right,
                                   result.size_left) > 10  # 28 px: not one grid
    # true correspondences: target pixels cast onto the truth DEM, seen by view_03
    camera = small_scene.cameras[small_scene.target]
    rows, cols = np.mgrid[3:camera.height:6, 3:camera.width:6]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    seen = small_scene.cameras["view_03"].project(target_points(small_scene, pixels))
    inside = np.all(np.isfinite(seen), axis=1) & np.all((seen > 0) & (seen < 191), axis=1)
    assert inside.sum() > 300
    row_error = (apply_homography(result.H_left, pixels[inside])[:, 1]
                 - apply_homography(result.H_right, seen[inside])[:, 1])
    assert np.sqrt(np.mean(row_error**2)) < 0.3  # 0.11 px
