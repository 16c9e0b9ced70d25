"""The synthetic rover pair (demtool.synth.rover): geometry and truth."""

from __future__ import annotations

import numpy as np

from demtool.synth.rover import Z_DOWN, _ground_hits, height_xy, make_rover_pair


def test_rays_hit_the_ground_surface():
    origin = np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(0)
    direction = np.column_stack([rng.uniform(-0.3, 0.3, 500), np.ones(500),
                                 -rng.uniform(0.2, 0.9, 500)])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    hit = _ground_hits(origin, direction)
    assert np.isfinite(hit).all()
    np.testing.assert_allclose(hit[:, 2], height_xy(hit[:, 0], hit[:, 1]), atol=1e-6)
    # the hits lie on the rays
    along = (hit - origin) @ direction.T
    np.testing.assert_allclose(np.linalg.norm(hit - origin, axis=1), np.diag(along))
    upward = _ground_hits(origin, np.array([[0.0, 1.0, 0.1]]))
    assert np.isnan(upward).all()


def test_pair_geometry_and_frames():
    up = make_rover_pair(width=64, height=48, focal_px=90.0, supersample=1)
    down = make_rover_pair(width=64, height=48, focal_px=90.0, supersample=1, z_down=True)
    np.testing.assert_allclose(up.left.center, [-0.15, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(down.left.center, Z_DOWN @ up.left.center, atol=1e-12)
    np.testing.assert_array_equal(up.left_image, down.left_image)  # same scene, same seed
    assert up.left_image.std() > 0.05 and not np.array_equal(up.left_image, up.right_image)
    point = np.array([[0.4, 3.0, 0.7]])
    assert up.truth_height(point)[0] == height_xy(0.4, 3.0)
    assert down.truth_height(Z_DOWN @ point[0])[0] == height_xy(0.4, 3.0)
    ground = down.truth_xyz(Z_DOWN @ point[0])[0]
    assert ground @ down.up == height_xy(0.4, 3.0)
