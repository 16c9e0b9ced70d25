"""demtool.sensors.pinhole: projection, rays, triangulation and conventions of other tools."""

import numpy as np
import pytest

from demtool.sensors import pinhole as cam


@pytest.fixture
def pair():
    nadir = cam.look_at([0, 0, 1000], [0, 0, 0], focal_px=1500, width=400, height=300)
    oblique = cam.look_at([350, 40, 950], [0, 0, 0], focal_px=1500, width=400, height=300)
    return nadir, oblique


def test_nadir_camera_orientation_is_east_right_south_down(pair):
    nadir, _ = pair
    centre = nadir.project(np.array([0.0, 0.0, 0.0]))
    east = nadir.project(np.array([10.0, 0.0, 0.0]))
    north = nadir.project(np.array([0.0, 10.0, 0.0]))
    np.testing.assert_allclose(centre, [199.5, 149.5])
    assert east[0] > centre[0] and abs(east[1] - centre[1]) < 1e-9
    assert north[1] < centre[1] and abs(north[0] - centre[0]) < 1e-9
    np.testing.assert_allclose(nadir.center, [0, 0, 1000])
    np.testing.assert_allclose(nadir.axis, [0, 0, -1], atol=1e-12)


def test_ray_and_backprojection_invert_projection(pair):
    _, oblique = pair
    points = np.random.default_rng(0).uniform(-80, 80, (50, 3))
    pixels = oblique.project(points)
    rays = oblique.rays(pixels)
    to_points = points - oblique.center
    along = np.sum(to_points * rays, axis=1)
    np.testing.assert_allclose(oblique.center + along[:, None] * rays, points, atol=1e-8)
    np.testing.assert_allclose(oblique.backproject(pixels, oblique.depth(points)), points,
                               atol=1e-8)


def test_points_behind_the_camera_project_to_nan(pair):
    nadir, _ = pair
    assert np.isnan(nadir.project(np.array([[0.0, 0.0, 2000.0]]))).all()


@pytest.mark.parametrize("method", [cam.triangulate_linear, cam.triangulate_midpoint])
def test_triangulation_recovers_points(pair, method):
    nadir, oblique = pair
    points = np.random.default_rng(1).uniform(-60, 60, (40, 3))
    np.testing.assert_allclose(method(nadir, oblique, nadir.project(points),
                                      oblique.project(points)), points, atol=1e-6)


def test_midpoint_distance_measures_inconsistent_matches(pair):
    nadir, oblique = pair
    points = np.zeros((1, 3))
    noisy = oblique.project(points) + [[0.0, 3.0]]  # off the epipolar line
    _, distance = cam.triangulate_midpoint(nadir, oblique, nadir.project(points), noisy,
                                           return_distance=True)
    assert distance[0] > 0.5


def test_opencv_round_trip(pair):
    import cv2

    _, oblique = pair
    K, rvec, tvec = cam.to_opencv(oblique)
    points = np.random.default_rng(2).uniform(-50, 50, (10, 3))
    projected, _ = cv2.projectPoints(points, rvec, tvec, K, None)
    np.testing.assert_allclose(projected.reshape(-1, 2), oblique.project(points), atol=1e-8)
    back = cam.from_opencv(K, rvec, tvec, oblique.width, oblique.height)
    np.testing.assert_allclose(back.R, oblique.R, atol=1e-12)


def test_pycolmap_round_trip_shifts_half_a_pixel(pair):
    _, oblique = pair
    colmap_camera, pose = cam.to_pycolmap(oblique)
    assert colmap_camera.principal_point_x == pytest.approx(oblique.K[0, 2] + 0.5)

    class FakeImage:
        cam_from_world = pose

    back = cam.from_pycolmap(FakeImage(), colmap_camera)
    np.testing.assert_allclose(back.K, oblique.K, atol=1e-9)
    np.testing.assert_allclose(back.R, oblique.R, atol=1e-9)
    np.testing.assert_allclose(back.t, oblique.t, atol=1e-9)


def test_camera_arrays_round_trip(pair):
    arrays = cam.cameras_to_arrays(["a", "b"], list(pair))
    restored = cam.cameras_from_arrays(arrays)
    np.testing.assert_allclose(restored["b"].P, pair[1].P)
