"""Calibrated rectification from sensor models (demtool.rectify.calibrated)."""

import numpy as np
import pytest

from demtool.errors import ProcessingError
from demtool.rectify.calibrated import (
    fit_pointing_correction,
    match_residuals,
    pixels_to_rect,
    rect_to_pixels,
    rectified_geometry,
    rectify_sensors,
    rectifying_rotation,
    resampling_maps,
    warp,
)
from demtool.sensors.arrays import rotate_pointing, rotation_vector_matrix
from tests.helpers.frame_scene import MOON_RADIUS, make_frame_scene


@pytest.fixture(scope="module")
def scene():
    return make_frame_scene(size=128, seed=3)


def _ground_points(scene, count=400, seed=0):
    """Body-fixed points on the terrain seen by both cameras, and their pixels (x, y)."""
    rng = np.random.default_rng(seed)
    lines = rng.uniform(10, scene.left.lines - 10, count)
    samples = rng.uniform(10, scene.left.samples - 10, count)
    xyz = scene.left.image_to_ground(lines, samples, height=rng.uniform(-20, 30, count))
    keep = np.ones(count, bool)
    pts = []
    for model in (scene.left, scene.right):
        line, sample = model.ground_to_image(xyz)
        keep &= (line > 0) & (line < model.lines) & (sample > 0) & (sample < model.samples)
        pts.append(np.stack([sample - 0.5, line - 0.5], axis=-1))
    return xyz[keep], pts[0][keep], pts[1][keep]


def test_rectifying_rotation_is_fusiellos_frame():
    R = rectifying_rotation([0, 0, 0], [3.0, 0.1, 0.2], np.array([0.05, 0.0, 1.0]) / np.hypot(
        0.05, 1.0))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R[0], np.array([3.0, 0.1, 0.2]) / np.linalg.norm([3, 0.1, 0.2]))
    assert R[2, 2] > 0.99  # z stays near the boresight
    with pytest.raises(ProcessingError, match="same centre"):
        rectifying_rotation([1, 2, 3], [1, 2, 3], [0, 0, 1.0])


def test_true_correspondences_share_rectified_rows(scene):
    geometry = rectified_geometry(scene.left, scene.right)
    _, pl, pr = _ground_points(scene)
    xl, yl, xr, yr = match_residuals(scene.left, scene.right, geometry.R_rect, geometry.f_px,
                                     pl, pr)
    assert len(pl) > 200
    np.testing.assert_allclose(yl, yr, atol=1e-6)  # distortion included
    assert np.all(xl - xr > -20) and np.ptp(xl - xr) > 1.0  # parallax along the rows


def test_rect_to_pixels_inverts_pixels_to_rect(scene):
    geometry = rectified_geometry(scene.left, scene.right, disparity_offset=3.5)
    lines = np.array([0.5, 20.25, 64.0, 127.5])
    samples = np.array([127.5, 3.75, 64.0, 0.5])
    for side, model, cx in (("left", scene.left, geometry.cx_left),
                            ("right", scene.right, geometry.cx_right)):
        x, y = pixels_to_rect(model, geometry.R_rect, geometry.f_px, lines, samples)
        line, sample = rect_to_pixels(model, geometry, side, x + cx, y + geometry.cy, 1.0e4)
        np.testing.assert_allclose(line, lines, atol=1e-6)
        np.testing.assert_allclose(sample, samples, atol=1e-6)
    assert geometry.cx_right - geometry.cx_left == pytest.approx(3.5)


def test_resampling_maps_undo_the_distortion(scene):
    """The warped left image equals the image rendered through a distortion-free camera
    with the rectified orientation (same rays), away from the borders."""
    _, pl, pr = _ground_points(scene, seed=5)
    plain = rectified_geometry(scene.left, scene.right)
    xl, _, xr, _ = match_residuals(scene.left, scene.right, plain.R_rect, plain.f_px, pl, pr)
    geometry = rectified_geometry(scene.left, scene.right,
                                  disparity_offset=float(np.median(xl - xr)))
    assert geometry.size_rect[0] < 1.2 * scene.left.samples  # the pair now overlaps
    map_x, map_y = resampling_maps(scene.left, geometry, "left")
    warped = warp(scene.left_image, map_x, map_y)
    assert warped.shape == tuple(geometry.size_rect[::-1])
    assert np.isnan(warped).mean() < 0.3
    # a ground point's rectified position maps back to its original pixel
    x, y = pixels_to_rect(scene.left, geometry.R_rect, geometry.f_px, pl[:, 1] + 0.5,
                          pl[:, 0] + 0.5)
    col, row = x + geometry.cx_left, y + geometry.cy
    np.testing.assert_allclose(map_x[np.rint(row).astype(int), np.rint(col).astype(int)],
                               pl[:, 0] + (np.rint(col) - col) * 1.0, atol=0.6)


def test_pointing_correction_recovers_a_known_rotation(scene):
    geometry = rectified_geometry(scene.left, scene.right)
    omega_true = np.array([2.0e-3, 0.0, -1.5e-3])  # rectified frame
    turn = geometry.R_rect.T @ rotation_vector_matrix(omega_true) @ geometry.R_rect
    # the given (wrong) model is the true one turned the other way
    wrong = rotate_pointing(scene.right, turn.T)
    _, pl, pr = _ground_points(scene)
    # pixels of the matches as the real (true) right camera saw them
    _, yl, _, _ = match_residuals(scene.left, wrong, geometry.R_rect, geometry.f_px, pl, pr)
    fit = fit_pointing_correction(wrong, geometry.R_rect, geometry.f_px, pr, yl)
    np.testing.assert_allclose(fit.omega_rect, omega_true, atol=2e-5)
    assert np.sqrt(np.mean(fit.residuals_before ** 2)) > 5.0
    assert np.abs(fit.residuals_after).max() < 0.05


def test_rectify_sensors_corrects_or_refuses(scene):
    geometry = rectified_geometry(scene.left, scene.right)
    _, pl, pr = _ground_points(scene)
    small = geometry.R_rect.T @ rotation_vector_matrix([1.5e-3, 0, 0]) @ geometry.R_rect
    result = rectify_sensors(scene.left, rotate_pointing(scene.right, small), pl, pr)
    assert result.corrected
    np.testing.assert_allclose(result.fit.omega_rect, [-1.5e-3, 0, 0], atol=2e-5)
    rows = result.points_left_rect[:, 1] - result.points_right_rect[:, 1]
    assert np.abs(rows).max() < 0.05
    assert result.disparity_range[0] < 0 < result.disparity_range[1]
    clean = rectify_sensors(scene.left, scene.right, pl, pr)
    assert not clean.corrected
    large = geometry.R_rect.T @ rotation_vector_matrix([30e-3, 0, 0]) @ geometry.R_rect
    with pytest.raises(ProcessingError, match=r"the SPICE is off.*demtool bundle --sensors"):
        rectify_sensors(scene.left, rotate_pointing(scene.right, large), pl, pr)
    rng = np.random.default_rng(1)
    noisy = pr + rng.normal(0, 6.0, pr.shape)
    with pytest.raises(ProcessingError, match="the SPICE is off"):
        rectify_sensors(scene.left, scene.right, pl, noisy)


def test_moon_radius_constant():
    assert MOON_RADIUS == 1737400.0


def test_local_models_are_not_told_about_spice():
    """Local-frame pinholes (a rover's) whose relative pose is off: the message names the
    options that apply to them, not `bundle --sensors` and SPICE."""
    from demtool.sensors.pinhole import look_at

    left = look_at((-0.15, 0, 1), (-0.15, 3, 0), up=(0, 0, 1), focal_px=300, width=200,
                   height=150)
    right = look_at((0.15, 0, 1), (0.15, 3, 0), up=(0, 0, 1), focal_px=300, width=200,
                    height=150)
    rng = np.random.default_rng(0)
    pixels = np.column_stack([rng.uniform(5, 195, 300), rng.uniform(40, 145, 300)])
    rays = left.rays(pixels)
    s = -left.center[2] / rays[:, 2]
    ground = left.center + s[:, None] * rays  # on the plane Z = 0
    pl = left.project(ground)
    tilted = look_at((0.15, 0, 1), (0.15, 3, 0.5), up=(0, 0, 1), focal_px=300, width=200,
                     height=150)  # 40 mrad off in pitch
    pr = tilted.project(ground)
    keep = np.isfinite(pr).all(axis=1) & (pr[:, 1] > 0) & (pr[:, 1] < 150)
    with pytest.raises(ProcessingError) as info:
        rectify_sensors(left, right, pl[keep], pr[keep])
    message = str(info.value)
    assert "--max-vertical-residual" in message and "relative pose" in message
    assert "SPICE" not in message and "bundle" not in message
