"""Every sensor model is validated as it is read (issue 31, class 1 and 2): bad values in
ISDs, cubes, .tsai files and pinholes are refused in one line naming the file, the key
and the value; good models (and a one-state line scan, extended with its velocity) read."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.maps import enu_frame, lonlat_height_to_xyz
from demtool.sensors import FrameSensor, LineScanSensor, read_sensor
from demtool.sensors.validate import check_named_body
from tests.helpers.camera_isd import MOON_RADIUS, look_at_rotation, nadir_isd
from tests.helpers.linescan import isd_dict, linescan_sensor
from tests.sensors.test_isis_apollo import write_cube
from tests.sensors.test_tsai import HEADER, MOON

CAMERA = dict(focal_mm=50.0, pitch_mm=0.01, lines=64, samples=64)


def _frame() -> dict:
    return nadir_isd(10.0, 5.0, 50_000.0, **CAMERA)


def _write(tmp_path, isd, name="cam.json"):
    path = tmp_path / name
    path.write_text(json.dumps(isd))  # NaN and Infinity as JSON's extension writes them
    return path


def _set(isd, key, value):
    isd = copy.deepcopy(isd)
    *head, last = key.split(".")
    block = isd
    for part in head:
        block = block[part]
    block[last] = value
    return isd


def test_good_frame_and_linescan_read(tmp_path):
    frame = read_sensor(_write(tmp_path, _frame()))
    assert isinstance(frame, FrameSensor)
    ls = read_sensor(_write(tmp_path, isd_dict(linescan_sensor(lines=40, samples=30)), "ls.json"))
    assert isinstance(ls, LineScanSensor)


SHEARED = [1.0, 0.2, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
MIRROR = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0]

FRAME_CASES = [
    ("focal_length_model.focal_length", float("nan"), "not a finite number"),
    ("focal_length_model.focal_length", float("inf"), "not a finite number"),
    ("focal_length_model.focal_length", 0.0, "must be positive"),
    ("focal_length_model.focal_length", -50.0, "must be positive"),
    ("focal_length_model.focal_length", "fifty", "not a number"),
    ("focal2pixel_lines", [0.0, 0.0, 0.0], "not invertible"),
    ("focal2pixel_samples", [0.0, 0.0, 100.0], "not invertible"),
    ("instrument_pointing.quaternions", [[0.0, 0.0, 0.0, 0.0]], "all zero"),
    ("instrument_pointing.quaternions", [[2.0, 0.0, 0.0, 0.0]], "has norm 2"),
    ("instrument_pointing.constant_rotation", SHEARED, "is not a rotation"),
    ("instrument_pointing.constant_rotation", MIRROR, "is a reflection"),
    ("radii.semimajor", float("nan"), "not a finite number"),
    ("radii.semimajor", None, "not a number"),
    ("radii.semiminor", 0.0, "must be positive"),
    ("radii.semiminor", -1737400.0, "must be positive"),
    ("radii.semimajor", "1737.4", "not a number"),
    ("image_lines", float("nan"), "not a finite number"),
    ("image_lines", None, "not a number"),
    ("image_lines", 0, "must be positive"),
    ("image_samples", -64, "must be positive"),
    ("image_samples", "64", "not a number"),
    ("image_samples", 64.5, "not a whole number"),
    ("detector_center.line", None, "not a number"),
    ("detector_line_summing", -2, "must be positive"),  # 0 reads as 1 (CaSSIS modes)
    ("sun_position.positions", [[float("nan"), 0.0, 0.0]], "non-finite"),
]


@pytest.mark.parametrize("key, value, message", FRAME_CASES,
                         ids=[f"{k}={v!r}" for k, v, _ in FRAME_CASES])
def test_frame_isd_bad_values(tmp_path, key, value, message):
    path = _write(tmp_path, _set(_frame(), key, value))
    with pytest.raises(InputError) as info:
        read_sensor(path)
    text = str(info.value)
    assert text.startswith(str(path)) and "\n" not in text
    assert message in text
    assert key.split(".")[-1] in text or "focal2pixel" in text


def test_times_running_backwards(tmp_path):
    isd = _frame()
    isd["body_rotation"] = {"quaternions": [[1.0, 0, 0, 0]] * 2, "ephemeris_times": [1.0, 0.0]}
    with pytest.raises(InputError, match=r"body_rotation\.ephemeris_times.*not strictly "
                                         "increasing"):
        read_sensor(_write(tmp_path, isd))


def test_positions_in_km_labelled_metres(tmp_path):
    isd = _frame()
    block = isd["instrument_position"]
    block["positions"] = (np.asarray(block["positions"]) / 1000.0).tolist()  # km, unit "m"
    with pytest.raises(InputError, match=r"instrument_position\.positions.*inside the body.*"
                                         r"km labelled metres"):
        read_sensor(_write(tmp_path, isd))


def test_camera_at_the_centre_of_the_body(tmp_path):
    isd = _set(_frame(), "instrument_position.positions", [[0.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="inside the body"):
        read_sensor(_write(tmp_path, isd))


def test_camera_looking_past_the_body(tmp_path):
    from tests.helpers.camera_isd import frame_isd

    east, north, up = enu_frame(10.0, 5.0)
    position = lonlat_height_to_xyz(10.0, 5.0, 50_000.0, radii=MOON_RADIUS)
    rotation = look_at_rotation(position, position + 1e6 * east, north)
    with pytest.raises(InputError, match="looks away from the body"):
        read_sensor(_write(tmp_path, frame_isd(position, rotation, **CAMERA)))


def test_limb_image_passes_with_a_note(tmp_path):
    """Centre ray above the horizon, the lower edge on the surface: read, with a note."""
    from tests.helpers.camera_isd import frame_isd

    east, north, up = enu_frame(10.0, 5.0)
    altitude = 50_000.0
    position = lonlat_height_to_xyz(10.0, 5.0, altitude, radii=MOON_RADIUS)
    horizon_dip = np.arccos(MOON_RADIUS / (MOON_RADIUS + altitude))  # ≈ 13.3°
    look = np.cos(horizon_dip - 0.02) * north - np.sin(horizon_dip - 0.02) * up
    rotation = look_at_rotation(position, position + 1e6 * look, east)
    model = read_sensor(_write(tmp_path, frame_isd(position, rotation, focal_mm=20.0,
                                                   pitch_mm=0.01, lines=512, samples=512)))
    assert any("limb" in note for note in model.notes)


def test_moon_radii_on_a_mars_isd(tmp_path):
    isd = _frame()
    isd["naif_keywords"] = {"BODY499_RADII": [3396.19, 3396.19, 3376.2], "BODY_CODE": 499}
    with pytest.raises(InputError, match=r"'radii'.*1737\.4 km.*BODY499_RADII, 3396\.19 km"):
        read_sensor(_write(tmp_path, isd))
    isd["naif_keywords"] = {"BODY_CODE": 499}  # radii from PROJ's Mars
    with pytest.raises(InputError, match=r"Mars \(NAIF 499\)"):
        read_sensor(_write(tmp_path, isd))
    isd["naif_keywords"] = {"BODY_CODE": 301}
    assert read_sensor(_write(tmp_path, isd)).radii[0] == MOON_RADIUS


def test_named_body_must_match_the_radii(tmp_path):
    from demtool.maps import body_by_name

    model = read_sensor(_write(tmp_path, _frame()))
    with pytest.raises(InputError, match=r"not those of --body Mars \(3396\.19 km\)"):
        check_named_body(model, body_by_name("Mars"), "cam.json")
    check_named_body(model, body_by_name("Moon"), "cam.json")


# -- line scan --------------------------------------------------------------------------


def test_linescan_lines_backwards(tmp_path):
    isd = isd_dict(linescan_sensor(lines=40, samples=30))
    isd["line_scan_rate"] = [[row[0], row[1], -row[2]] for row in isd["line_scan_rate"]]
    with pytest.raises(InputError, match=r"'line_scan_rate'.*seconds per line must be "
                                         "positive"):
        read_sensor(_write(tmp_path, isd))


def _one_state(sensor, center_time=1000.0, *, velocity=True):
    isd = isd_dict(sensor, center_time)
    position = sensor.position_at(np.array([0.0]))[0]
    dt = 1e-3
    v = (sensor.position_at(np.array([dt]))[0] - sensor.position_at(np.array([-dt]))[0]) / (2 * dt)
    isd["instrument_position"] = {"ephemeris_times": [center_time],
                                  "positions": [position.tolist()], "unit": "m"}
    if velocity:
        isd["instrument_position"]["velocities"] = [v.tolist()]
    return isd


def test_one_state_linescan_is_extended_with_its_velocity(tmp_path):
    """One state and its velocity: the first and last lines are exposed where the full
    orbit puts them (≤ 0.05 m on the ground), not from one standing point."""
    sensor = linescan_sensor(lines=200, samples=30, gsd=1.0)
    model = read_sensor(_write(tmp_path, _one_state(sensor)))
    lines = np.array([0.5, 100.0, 199.5])
    samples = np.full(3, 15.0)
    got = model.image_to_ground(lines, samples)
    want = sensor.image_to_ground(lines, samples)
    np.testing.assert_allclose(got, want, atol=0.05)
    assert np.linalg.norm(got[2] - got[0]) == pytest.approx(199.0, rel=0.02)  # 1 m/line


def test_one_state_linescan_without_velocity_is_refused(tmp_path):
    isd = _one_state(linescan_sensor(lines=40, samples=30), velocity=False)
    with pytest.raises(InputError, match="'instrument_position' has one state and no velocity"):
        read_sensor(_write(tmp_path, isd))


# -- ISIS cubes -------------------------------------------------------------------------

ALPHA = {"AlphaSamples": 22900, "AlphaLines": 22900, "AlphaStartingSample": 0.5,
         "AlphaStartingLine": 0.5, "AlphaEndingSample": 22900.5, "AlphaEndingLine": 22900.5,
         "BetaSamples": 229, "BetaLines": 229}


def test_cube_beta_samples_zero(tmp_path):
    path = write_cube(tmp_path / "beta.cub", alpha=ALPHA)
    path.write_bytes(path.read_bytes().replace(b"BetaSamples = 229", b"BetaSamples = 0  "))
    with pytest.raises(InputError, match=r"beta\.cub: key 'AlphaCube/BetaSamples' = 0: must be "
                                         "positive"):
        read_sensor(path)


@pytest.mark.parametrize("key, value, message", [
    ("BODY301_RADII", "(NaN, NaN, NaN)", "has non-finite values"),
    ("BODY301_RADII", "(a, b, c)", "not a list of numbers"),
    ("BODY301_RADII", "(0.0, 0.0, 0.0)", "radii must be positive"),
    ("BODY301_RADII", "(3396.19, 3396.19, 3376.2)", "of another body"),
    ("INS-915240_FOCAL_LENGTH", "-76.054", "must be positive"),
    ("INS-915240_FOCAL_LENGTH", "0.0", "must be positive"),
    ("INS-915240_ITRANSL", "(0.0, 0.0, 0.0)", "not invertible"),
])
def test_cube_bad_keywords(tmp_path, key, value, message):
    from tests.sensors.test_isis_apollo import NAIF

    path = write_cube(tmp_path / "bad.cub", naif={**NAIF, key: value})
    with pytest.raises(InputError) as info:
        read_sensor(path)
    assert str(info.value).startswith(str(path)) and message in str(info.value)


def test_cube_zero_quaternion_table(tmp_path):
    path = write_cube(tmp_path / "zeroq.cub")
    data = bytearray(path.read_bytes())
    data[8192:8192 + 32] = bytes(32)  # InstrumentPointing's J2000Q0..3
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"zeroq\.cub: key 'table InstrumentPointing"):
        read_sensor(path)


def test_cube_camera_in_metres_inside_the_body(tmp_path):
    path = write_cube(tmp_path / "inside.cub")
    data = bytearray(path.read_bytes())
    x = np.frombuffer(bytes(data[8192 + 80:8192 + 88]), "<f8")[0]  # InstrumentPosition X, km
    data[8192 + 80:8192 + 88] = np.array([x / 1000.0], "<f8").tobytes()
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"inside\.cub: key 'table InstrumentPosition'.*inside "
                                         "the body"):
        read_sensor(path)


def test_label_only_isis_cube(tmp_path):
    path = tmp_path / "only.cub"
    path.write_text("Object = IsisCube\n")
    with pytest.raises(InputError, match=r"only\.cub: cannot parse the ISIS label .*truncated"):
        read_sensor(path)


# -- .tsai and pinholes -----------------------------------------------------------------


def test_tsai_reflection_refused(tmp_path):
    path = tmp_path / "mirror.tsai"
    path.write_text(HEADER.replace("R = 0 0 -1 1 0 0 0 -1 0", "R = 0 0 -1 1 0 0 0 1 0")
                    + "NULL\n")
    with pytest.raises(InputError, match=r"mirror\.tsai: key 'R'.*reflection"):
        read_sensor(path)


def test_tsai_inside_the_body(tmp_path):
    path = tmp_path / "inside.tsai"
    path.write_text(HEADER.replace("C = 1837400 0 0", "C = 1837.4 0 0") + "NULL\n")
    with pytest.raises(InputError, match=r"inside\.tsai: key 'C'.*inside the body"):
        read_sensor(path, radii=MOON)


def test_pinhole_npz_reflection_refused(tmp_path):
    from demtool import io as dio
    from demtool.sensors.pinhole import PinholeCamera, cameras_to_arrays

    K = np.array([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]])
    good = PinholeCamera(K=K, R=np.eye(3), t=np.array([0, 0, 10.0]), width=64, height=64,
                         name="a")
    bad = PinholeCamera(K=K, R=np.diag([1.0, 1.0, -1.0]), t=np.array([0, 0, 10.0]), width=64,
                        height=64, name="b")
    path = tmp_path / "cameras.npz"
    dio.write_npz(path, "cameras", cameras_to_arrays(["a", "b"], [good, bad]))
    with pytest.raises(InputError, match=r"cameras\.npz \(b\): key 'R'.*reflection"):
        read_sensor(path, name="a")
