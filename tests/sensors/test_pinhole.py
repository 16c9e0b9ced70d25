"""PinholeCamera as a SensorModel, its Brown distortion, and the cameras NPZ field."""

import numpy as np
import pytest

from demtool import io as dio
from demtool.errors import InputError
from demtool.sensors import PinholeCamera, SensorModel, read_sensor, read_sensors
from demtool.sensors import pinhole as legacy
from demtool.sensors.pinhole import cameras_to_arrays, look_at

BROWN = np.array([-0.2, 0.05, 1e-3, -5e-4, 0.01])


def nadir(distortion=None):
    cam = look_at((10.0, -5.0, 500.0), (10.0, -5.0, 0.0), focal_px=800.0, width=640,
                  height=480)
    return PinholeCamera(K=cam.K, R=cam.R, t=cam.t, width=640, height=480,
                         distortion=distortion, name="view_00")


def test_legacy_names_are_the_same_objects():
    assert legacy.PinholeCamera is PinholeCamera
    assert isinstance(nadir(), SensorModel)


def test_csm_convention_and_plane_intersection():
    cam = nadir()
    # The principal point (319.5, 239.5) in (u, v) is (240, 320) in CSM (line, sample).
    ground = cam.image_to_ground(240.0, 320.0, 0.0)
    np.testing.assert_allclose(ground, (10.0, -5.0, 0.0), atol=1e-9)
    ground = cam.image_to_ground(240.0, 320.0 + 80.0, 2.0)   # 80 px right = east
    np.testing.assert_allclose(ground, (10.0 + 498.0 / 10.0, -5.0, 2.0), atol=1e-9)
    line, sample = cam.ground_to_image(ground)
    assert line == pytest.approx(240.0) and sample == pytest.approx(400.0)


@pytest.mark.parametrize("distortion", [None, BROWN])
def test_round_trip_and_rays(distortion):
    cam = nadir(distortion)
    lines, samples = np.meshgrid(np.linspace(0.5, 479.5, 9), np.linspace(0.5, 639.5, 9),
                                 indexing="ij")
    ground = cam.image_to_ground(lines, samples, 3.0)
    assert np.allclose(ground[..., 2], 3.0)
    line, sample = cam.ground_to_image(ground)
    assert np.max(np.hypot(line - lines, sample - samples)) < 1e-6
    ray = cam.image_to_ray(lines, samples)
    np.testing.assert_allclose(np.linalg.norm(ray.direction, axis=-1), 1.0)
    np.testing.assert_allclose(ray.origin[0, 0], cam.center)


def test_distortion_moves_corners_like_opencv():
    cv2 = pytest.importorskip("cv2")
    cam = nadir(BROWN)
    points = np.array([[100.0, 80.0, 0.0], [-60.0, 30.0, 0.0], [25.0, -70.0, 1.0]])
    rvec, _ = cv2.Rodrigues(cam.R)
    expected, _ = cv2.projectPoints(points, rvec, cam.t, cam.K, BROWN)
    np.testing.assert_allclose(cam.project(points), expected[:, 0], atol=1e-9)


def test_cameras_npz_with_and_without_distortion(tmp_path):
    plain, bent = nadir(), nadir(BROWN)
    path = dio.write_npz(tmp_path / "cameras.npz", "cameras",
                         cameras_to_arrays(["a", "b"], [plain, bent]))
    models = read_sensors(path)
    assert models["a"].distortion is None
    np.testing.assert_allclose(models["b"].distortion, BROWN)
    assert read_sensor(path, name="b").name == "b"
    with pytest.raises(InputError, match="holds 2 cameras"):
        read_sensor(path)
    # A format-1 file (no distortion key) still reads.
    old = tmp_path / "old.npz"
    arrays = cameras_to_arrays(["a"], [plain])
    np.savez(old, kind=np.array("cameras"), format_version=np.array(1), **arrays)
    assert read_sensor(old).distortion is None


def test_bad_distortion_field_names_file(tmp_path):
    arrays = cameras_to_arrays(["a"], [nadir(BROWN)])
    arrays["distortion"] = np.zeros((1, 3))
    path = dio.write_npz(tmp_path / "cameras.npz", "cameras", arrays)
    with pytest.raises(InputError, match=r"cameras\.npz.*distortion"):
        read_sensor(path)
