"""Frame models as arrays (rectify.npz) and pointing rotations (demtool.sensors.arrays)."""

import numpy as np
import pytest

from demtool.sensors.arrays import (
    model_from_arrays,
    model_to_arrays,
    model_type,
    rotate_pointing,
    rotation_vector_matrix,
)
from demtool.sensors.distortion import Distortion
from demtool.sensors.pinhole import PinholeCamera
from demtool.sensors.tsai import TsaiCamera
from tests.helpers.frame_scene import frame_camera

LINES = np.array([0.5, 10.25, 40.0, 63.5])
SAMPLES = np.array([63.5, 5.5, 32.0, 0.5])


def _models():
    frame = frame_camera([1.8e6, 1e3, 2e3], [1.7374e6, 0, 0], size=64, focal_mm=40.0, k1=0.02,
                         name="f")
    K = np.array([[500.0, 0, 31.5], [0, 510.0, 32.5], [0, 0, 1]])
    R = rotation_vector_matrix([0.1, -0.2, 0.05])
    pinhole = PinholeCamera(K=K, R=R, t=np.array([1.0, 2.0, 30.0]), width=64, height=64,
                            distortion=np.array([0.1, -0.01, 0.001, 0.002, 0.0]), name="p")
    tsai = TsaiCamera(K=K, R=R, t=np.array([1.0, 2.0, 30.0]), width=64, height=64, name="t",
                      lens_model=Distortion("photometrix", [0.001, 0.002, 1e-3, 0, 0, 0, 0]),
                      body_radii=(1737400.0, 1737400.0), pitch=0.01)
    return frame, pinhole, tsai


@pytest.mark.parametrize("index", [0, 1, 2])
def test_models_round_trip_through_arrays(index):
    model = _models()[index]
    arrays = model_to_arrays(model, "sensor_left_")
    assert all(key.startswith("sensor_left_") for key in arrays)
    back = model_from_arrays(arrays, "sensor_left_")
    assert model_type(back) == model_type(model) and back.name == model.name
    assert back.radii == model.radii
    a, b = model.image_to_ray(LINES, SAMPLES), back.image_to_ray(LINES, SAMPLES)
    np.testing.assert_allclose(b.direction, a.direction, atol=1e-14)
    np.testing.assert_allclose(b.origin, a.origin, atol=1e-9)


def test_missing_key_is_a_key_error():
    arrays = model_to_arrays(_models()[0], "s_")
    del arrays["s_rotation"]
    with pytest.raises(KeyError, match="s_rotation"):
        model_from_arrays(arrays, "s_")


@pytest.mark.parametrize("index", [0, 1])
def test_rotate_pointing_turns_rays_about_the_centre(index):
    model = _models()[index]
    turn = rotation_vector_matrix([3e-3, -2e-3, 1e-3])
    turned = rotate_pointing(model, turn)
    before, after = model.image_to_ray(LINES, SAMPLES), turned.image_to_ray(LINES, SAMPLES)
    np.testing.assert_allclose(after.direction, before.direction @ turn.T, atol=1e-12)
    np.testing.assert_allclose(after.origin, before.origin, atol=1e-6)


def test_rotation_vector_matrix():
    R = rotation_vector_matrix([0, 0, np.pi / 2])
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rotation_vector_matrix([0, 0, 0]), np.eye(3))
