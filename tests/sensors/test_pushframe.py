"""Push-frame sensor (usgscsm UsgsAstroPushFrameSensorModel) against usgscsm's published
test expectations (tests/PushFrameCameraTests.cpp, fixture OrbitalPushFrameSensorModel on
tests/data/orbitalPushFrame.json, copied to tests/sensors/data; USGS, public domain)."""

import json
from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import read_sensor
from demtool.sensors.isd import sensor_from_isd
from demtool.sensors.pushframe import PushFrameSensor

DATA = Path(__file__).parent / "data"
ISD = DATA / "orbitalPushFrame.json"


@pytest.fixture(scope="module")
def model():
    return read_sensor(ISD)


def test_reads_as_push_frame(model):
    assert isinstance(model, PushFrameSensor) and model.kind == "pushframe"
    assert model.image_size == (360, 16) and model.n_framelets == 30


def test_center(model):
    # usgscsm: imageToGround((6, 8), 0) = (1000000, 0, 0) to 1e-9 m;
    # groundToImage((1000000, 0, 0)) = (6, 8) to 0.001 px.
    np.testing.assert_allclose(model.image_to_ground(6.0, 8.0, 0.0), [1e6, 0.0, 0.0],
                               rtol=0, atol=1e-6)
    line, sample = model.ground_to_image(np.array([1e6, 0.0, 0.0]))
    assert line == pytest.approx(6.0, abs=1e-3) and sample == pytest.approx(8.0, abs=1e-3)


def test_framelet_times(model):
    # starting 998.475, exposure 0.05, delay 0.1, centre 1000: framelet k at
    # -1.5 + 0.1 k seconds; line 6 is in framelet 0, line 113.9 in framelet 9.
    np.testing.assert_allclose(model.line_time([6.0, 11.99, 12.0, 113.9]),
                               [-1.5, -1.5, -1.4, -0.6], atol=1e-12)


def test_sun_position_lagrange(model):
    # usgscsm getSunPositionLagrange: the sun at -0.6 s is 125000000 m on each axis (1e-5).
    np.testing.assert_allclose(model.sun_position(np.array(113.9)), [1.25e8] * 3,
                               rtol=0, atol=1e-5)


def test_image_to_ground_height(model):
    # usgscsm ImageToGroundHeight: 100 m of height moves the point 100 m (0.01).
    low = model.image_to_ground(6.0, 8.0, 0.0)
    high = model.image_to_ground(6.0, 8.0, 100.0)
    assert np.linalg.norm(high - low) == pytest.approx(100.0, abs=0.01)


def test_inversion_every_pixel(model):
    # usgscsm Inversion allows 10 px (framelets overlap); on this fixture the framelets
    # do not overlap and the round trip closes to 1e-6 px everywhere.
    line, sample = np.meshgrid(np.arange(0.5, 360), np.arange(0.5, 16), indexing="ij")
    back_line, back_sample = model.ground_to_image(model.image_to_ground(line, sample))
    np.testing.assert_allclose(back_line, line, atol=1e-6)
    np.testing.assert_allclose(back_sample, sample, atol=1e-6)


def _isd():
    return json.loads(ISD.read_text())


def test_reversed_and_flipped_framelets_round_trip():
    isd = _isd()
    isd["framelet_order_reversed"] = True
    isd["framelets_flipped"] = True
    model = sensor_from_isd(isd, "flip.json")
    # Reversed order: the first framelet of the image was exposed last.
    assert model.line_time(6.0) == pytest.approx(-1.5 + 29 * 0.1)
    line, sample = np.meshgrid(np.arange(0.5, 360, 7), np.arange(0.5, 16, 3), indexing="ij")
    back = model.ground_to_image(model.image_to_ground(line, sample),
                                 framelet=model.framelet(line))
    np.testing.assert_allclose(back[0], line, atol=1e-6)
    np.testing.assert_allclose(back[1], sample, atol=1e-6)


def test_overlapping_framelets_pick_the_nearest_middle():
    # Twice the framelet height on the same timing: each ground point is seen by two
    # framelets; ground_to_image returns the one whose middle line is nearest, and the
    # framelet hint returns the other.
    isd = _isd()
    isd["framelet_height"] = 24
    isd["image_lines"] = 720
    isd["detector_center"]["line"] = 12.0
    model = sensor_from_isd(isd, "overlap.json")
    ground = model.image_to_ground(np.array([12.0 + 24 * 10]), np.array([8.0]))
    line, _ = model.ground_to_image(ground)
    assert line[0] == pytest.approx(252.0, abs=1e-6)
    other, _ = model.ground_to_image(ground, framelet=11)
    assert 264.0 <= other[0] < 288.0 and abs(other[0] - line[0]) > 12


@pytest.mark.parametrize("key", ["framelet_height", "exposure_duration", "interframe_delay",
                                 "framelet_order_reversed"])
def test_push_frame_isd_without_framelet_keys_is_refused(key):
    isd = _isd()
    del isd[key]
    with pytest.raises(InputError, match=rf"pf\.json: ISD lacks the key '{key}'"):
        sensor_from_isd(isd, "pf.json")


def test_push_frame_isd_with_bad_framelet_values_is_refused():
    isd = _isd()
    isd["framelet_height"] = 0
    with pytest.raises(InputError, match=r"pf\.json: .*framelet height 0"):
        sensor_from_isd(isd, "pf.json")
    isd = _isd()
    isd["framelets_flipped"] = "no"
    with pytest.raises(InputError, match=r"pf\.json: ISD key 'framelets_flipped' is 'no'"):
        sensor_from_isd(isd, "pf.json")


def test_push_frame_isd_with_a_nan_framelet_key_is_refused_in_one_line():
    """Issue 46: a NaN framelet_height was a ValueError traceback."""
    isd = _isd()
    isd["framelet_height"] = float("nan")
    with pytest.raises(InputError, match=r"pf\.json: ISD key 'framelet_height' is nan"):
        sensor_from_isd(isd, "pf.json")


def test_push_frame_timing_off_the_ephemeris_names_the_framelet_keys():
    """Issue 46: framelet times outside the ephemeris are blamed on the timing keys, not
    on instrument_position alone."""
    isd = _isd()
    isd["starting_ephemeris_time"] += 1e6
    with pytest.raises(InputError, match=r"pf\.json: no image line .*starting_ephemeris_time"):
        sensor_from_isd(isd, "pf.json")


def test_push_frame_gives_a_ray_at_the_image_edge(model):
    """Issue 46: line = image_lines (the last framelet's bottom edge) has a ray, continuous
    with the lines just above it (no "limb" for a nadir view)."""
    edge = float(model.lines)
    xyz = model.image_to_ground(np.array([edge - 1e-3, edge]), np.array([8.0, 8.0]))
    assert np.isfinite(xyz).all()
    assert np.linalg.norm(xyz[1] - xyz[0]) < 1.0  # 1e-3 line apart: well under a metre
