"""The ISD writer (demtool.sensors.isd.isd_from_sensor / write_isd): read back, same model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demtool.sensors import FrameSensor, read_isd, read_sensor, sensor_from_isd
from demtool.sensors.base import Detector
from demtool.sensors.distortion import Distortion
from demtool.sensors.isd import isd_from_sensor, write_isd

DATA = Path(__file__).parent / "data"


def image_grid(model, n=9):
    return np.meshgrid(np.linspace(0.5, model.lines - 0.5, n),
                       np.linspace(0.5, model.samples - 0.5, n), indexing="ij")


def assert_same_geometry(first, second, tol_px=1e-6):
    """Ground points of ``first`` at two heights project to the same pixels through both;
    rays, camera centres and sun positions agree."""
    lines, samples = image_grid(first)
    for height in (0.0, 500.0):
        ground = first.image_to_ground(lines, samples, height)
        l1, s1 = first.ground_to_image(ground)
        l2, s2 = second.ground_to_image(ground)
        ok = np.isfinite(l1)
        assert ok.sum() >= 40
        assert np.max(np.hypot(l1 - l2, s1 - s2)[ok]) < tol_px
    r1, r2 = first.image_to_ray(lines, samples), second.image_to_ray(lines, samples)
    np.testing.assert_allclose(r2.origin, r1.origin, atol=1e-6)
    np.testing.assert_allclose(r2.direction, r1.direction, atol=1e-12)
    np.testing.assert_allclose(second.sun_position(lines[:, 0]), first.sun_position(lines[:, 0]),
                               rtol=1e-12, atol=1e-3)
    assert second.image_size == first.image_size
    assert second.radii == pytest.approx(first.radii, rel=1e-15)


@pytest.mark.parametrize("name", ["orbitalFramer", "orbitalLineScan", "constVelocityLineScan"])
def test_fixture_isds_round_trip(tmp_path, name):
    model = read_isd(DATA / f"{name}.json")
    path = write_isd(tmp_path / f"{name}.json", model)
    again = read_sensor(path)
    assert type(again) is type(model)
    assert_same_geometry(model, again)
    assert json.loads(path.read_text())["name_model"] == json.loads(
        (DATA / f"{name}.json").read_text())["name_model"]


def lunar_frame(distortion=None, z_direction=1.0):
    """A frame camera 50 km above the Moon's equator at 0° E, looking 10° off nadir."""
    radius = 1737400.0
    angle = np.radians(10.0)
    # sensor axes (columns) in the body frame: z toward the body, tilted about Y
    z = np.array([-np.cos(angle), 0.0, np.sin(angle)])
    x = np.array([0.0, 1.0, 0.0])
    rotation = np.column_stack([x, np.cross(z, x), z])
    pitch = 0.007
    detector = Detector(itrans_sample=np.array([0.0, 1 / pitch, 0.0]),
                        itrans_line=np.array([0.0, 0.0, 1 / pitch]),
                        center_sample=512.0, center_line=384.0)
    if z_direction < 0:
        rotation = rotation @ np.diag([-1.0, -1.0, 1.0])
    return FrameSensor(position=[radius + 50000.0, 0.0, 0.0], rotation=rotation,
                       focal_length=610.0, detector=detector, distortion=distortion,
                       lines=768, samples=1024, radii=(radius, radius),
                       sun=[1.4e11, 3e10, 1e9], name="lunar", time=12.5,
                       z_direction=z_direction)


@pytest.mark.parametrize("distortion", [
    None,
    Distortion("radial", [0.0, 2e-6, -1e-10]),
    Distortion("transverse", np.r_[0, 1, 0, 1e-6, 0, 0, 0, 0, 0, 0,
                                   0, 0, 1, 0, 1e-6, 0, 0, 0, 0, 0]),
    Distortion("kaguyalism", [0.01, 0, 1e-6, 0, 0, -0.02, 0, 0, 1e-6, 0]),
])
def test_frame_sensor_round_trip(distortion):
    model = lunar_frame(distortion)
    again = sensor_from_isd(json.loads(json.dumps(isd_from_sensor(model))))
    assert_same_geometry(model, again)
    expected = "radial" if distortion is None else distortion.model  # ALE's ideal lens
    assert again.distortion.model == expected


def test_z_direction_is_folded_into_the_attitude():
    model = lunar_frame(z_direction=-1.0)
    again = sensor_from_isd(isd_from_sensor(model))
    assert again.z_direction == 1.0
    assert_same_geometry(model, again)


def test_isd_keys_follow_ale():
    isd = isd_from_sensor(lunar_frame())
    assert isd["name_model"] == "USGS_ASTRO_FRAME_SENSOR_MODEL"
    assert isd["radii"] == {"semimajor": 1737.4, "semiminor": 1737.4, "unit": "km"}
    assert isd["instrument_position"]["positions"] == [[1787.4, 0.0, 0.0]]
    assert isd["body_rotation"]["quaternions"] == [[1.0, 0.0, 0.0, 0.0]]
    # the pointing quaternion (scalar-first, J2000 = body → sensor) maps the body's
    # direction to the sensor's +z axis
    w, x, y, z = isd["instrument_pointing"]["quaternions"][0]
    from demtool.sensors.base import quaternion_to_matrix

    to_sensor = quaternion_to_matrix([x, y, z, w])
    look = to_sensor @ np.array([-np.cos(np.radians(10.0)), 0.0, np.sin(np.radians(10.0))])
    np.testing.assert_allclose(look, [0.0, 0.0, 1.0], atol=1e-12)


def test_models_without_body_are_refused():
    from demtool.sensors import PinholeCamera

    camera = PinholeCamera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=8, height=8)
    with pytest.raises(ValueError, match="no body radii"):
        isd_from_sensor(camera)
