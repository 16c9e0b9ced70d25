"""Stand-ins for the held-out files of issue 41 (small synthetic ISDs written in tmp_path):
each form the reference tools accept loads through ``read_sensor`` and closes image →
ground → image within 0.01 px; usgscsm's published values where it has them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.maps import enu_frame
from demtool.sensors import LineScanSensor, ray_ellipsoid_intersection, read_sensor
from demtool.sensors.body_view import height_above_ellipsoid
from tests.helpers.camera_isd import frame_isd, look_at_rotation, nadir_isd
from tests.helpers.linescan import isd_dict, linescan_sensor

DATA = Path(__file__).parent / "data"
MARS = (3396190.0, 3376200.0)
EARTH = (6378137.0, 6356752.3)


def _write(tmp_path, isd, name="cam.json"):
    path = tmp_path / name
    path.write_text(json.dumps(isd))
    return path


def _round_trip(model, lines, samples, height=0.0):
    """Largest pixel error of image → ground → image over the rays that meet the
    ellipsoid raised by ``height``, and how many meet it."""
    ray = model.image_to_ray(lines, samples)
    ground, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, *model.radii, height,
                                             return_hit=True)
    back = model.ground_to_image(ground[hit])
    return float(np.max(np.hypot(back[0] - lines[hit], back[1] - samples[hit]))), int(hit.sum())


def _grid(model, n=17):
    return np.meshgrid(np.linspace(0.5, model.lines - 0.5, n),
                       np.linspace(0.5, model.samples - 0.5, n), indexing="ij")


def _on_ellipsoid(lon, lat, height, a, b):
    """Body-fixed point ``height`` metres along its radius from the ellipsoid's surface."""
    lon, lat = np.radians(lon), np.radians(lat)
    u = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    r = 1.0 / np.sqrt((u[0] ** 2 + u[1] ** 2) / a ** 2 + u[2] ** 2 / b ** 2)
    return u * (r + height)


def test_mars_rover_below_the_datum_with_cahvor(tmp_path):
    """A mast camera 0.9 km below the Mars ellipsoid (a rover in a crater) loads, is named
    a surface camera, and closes on the ground 2 m below it."""
    a, b = MARS
    lon, lat = 137.4, -4.6
    position = _on_ellipsoid(lon, lat, -900.0, a, b)
    east, north, up = enu_frame(lon, lat)
    target = position + 10.0 * north - 4.0 * up  # 22° below the horizon
    isd = frame_isd(position, look_at_rotation(position, target, east), focal_mm=34.0,
                    pitch_mm=0.012, lines=96, samples=128, radius=a)
    isd["radii"] = {"semimajor": a / 1e3, "semiminor": b / 1e3, "unit": "km"}
    isd["optical_distortion"] = {"cahvor": {"coefficients": [0.0, -2e-4, 1e-7, 0.05, -0.03]}}
    model = read_sensor(_write(tmp_path, isd))
    assert height_above_ellipsoid(model.position, a, b) == pytest.approx(-900.0, abs=1e-3)
    assert model.distortion.model == "cahvor"
    assert getattr(model, "surface_camera", False)
    assert any("surface camera" in note for note in model.notes)
    error, hits = _round_trip(model, *_grid(model), height=-902.0)
    assert hits > 100 and error <= 0.01


def test_positions_in_km_labelled_metres_put_a_mars_camera_inside(tmp_path):
    """The factor 1000 of a unit mix-up is far deeper than any relief: refused."""
    a, b = MARS
    isd = nadir_isd(137.4, -4.6, 300_000.0, focal_mm=50.0, pitch_mm=0.01, lines=32,
                    samples=32, radius=a)
    block = isd["instrument_position"]
    block["positions"] = (np.asarray(block["positions"]) / 1000.0).tolist()
    with pytest.raises(InputError, match="inside the body.*Mars's relief.*km labelled metres"):
        read_sensor(_write(tmp_path, isd))


def test_earth_flyby_limb_frame(tmp_path):
    """Earth fills ~8 % of the frame, away from the centre, corners and edge midpoints:
    loads with the fraction in a note and closes on the rays that meet it."""
    a, b = EARTH
    rho = np.radians(2.4)  # angular radius of the Earth
    position = np.array([a / np.sin(rho), 0.0, 0.0])
    to_earth = -position / np.linalg.norm(position)
    off = np.radians(4.0)  # the planet's centre 4° right and 4° down of the boresight
    x_axis, y_axis = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    look = (to_earth - np.tan(off) * x_axis - np.tan(off) * y_axis)
    look /= np.linalg.norm(look)
    rotation = look_at_rotation(position, position + look, x_axis)
    isd = frame_isd(position, rotation, focal_mm=20.0, pitch_mm=0.01, lines=512,
                    samples=512, radius=a)
    isd["radii"] = {"semimajor": a, "semiminor": b, "unit": "m"}
    model = read_sensor(_write(tmp_path, isd))
    note = next(n for n in model.notes if "limb" in n)
    fraction = float(note.split("(")[1].split(" %")[0]) / 100.0
    assert 0.04 < fraction < 0.12
    error, hits = _round_trip(model, *_grid(model, 65))
    assert hits > 100 and error <= 0.01


def test_camera_that_sees_no_surface(tmp_path):
    """Looking past the body: refused for the stages that need ground, read for
    ``camera`` (with a note saying so)."""
    position = np.array([3e7, 0.0, 0.0])
    rotation = look_at_rotation(position, position + np.array([0.0, 1e6, 0.0]),
                                np.array([0.0, 0.0, 1.0]))
    path = _write(tmp_path, frame_isd(position, rotation, focal_mm=20.0, pitch_mm=0.01,
                                      lines=64, samples=64))
    with pytest.raises(InputError, match="looks away from the body.*this stage needs ground"):
        read_sensor(path)
    model = read_sensor(path, require_surface=False)
    assert any("sees no surface" in note for note in model.notes)


def test_gapped_line_scan_loads_its_covered_lines(tmp_path):
    """An ephemeris covering 44 % of the lines: the others are masked, the covered ones
    load, close, and agree with the full ephemeris's model (no NaN leaks into them)."""
    sensor = linescan_sensor(lines=400, samples=40, gsd=2.0)
    full = isd_dict(sensor)
    isd = json.loads(json.dumps(full))
    block = isd["instrument_position"]
    start = isd["center_ephemeris_time"] + sensor.line_time(0.0)
    stop = isd["center_ephemeris_time"] + sensor.line_time(0.44 * sensor.lines)
    keep = [i for i, t in enumerate(block["ephemeris_times"]) if t <= stop]
    assert block["ephemeris_times"][keep[-1]] > start
    for key in ("ephemeris_times", "positions"):
        block[key] = [block[key][i] for i in keep]
    model = read_sensor(_write(tmp_path, isd))
    reference = read_sensor(_write(tmp_path, full, "full.json"))
    lines, samples = _grid(model, 41)
    ray = model.image_to_ray(lines, samples)
    covered = np.all(np.isfinite(ray.origin), axis=-1)[:, 0]
    assert 0.40 <= covered.mean() <= 0.55
    assert covered[0] and not covered[-1]
    assert any("masked" in note or "outside" in note for note in getattr(model, "notes", []))
    ground = model.image_to_ground(lines[covered], samples[covered])
    np.testing.assert_allclose(ground, reference.image_to_ground(lines[covered],
                                                                 samples[covered]), atol=0.05)
    inner = covered & (lines[:, 0] < lines[covered, 0].max() - 1.0)  # off the cut line
    error, hits = _round_trip(model, lines[inner], samples[inner])
    assert hits == inner.sum() * lines.shape[1] and error <= 0.01


def _lunar_orbiter_isd():
    isd = nadir_isd(10.0, 5.0, 50_000.0, focal_mm=610.0, pitch_mm=0.005, lines=200,
                    samples=300)
    isd["optical_distortion"] = {"lunarorbiter": {
        "perspective_x": 1.2e-5, "perspective_y": -0.8e-5, "center_point_x": 0.02,
        "center_point_y": -0.015}}
    isd["naif_keywords"] = {"INS-533001_OD_K": [1e-6, 2e-9],
                            "INS-533001_FOCAL_LENGTH": 610.0}
    return isd


def test_lunar_orbiter_radial_terms_from_naif_keywords(tmp_path):
    """ALE leaves k0, k1 in ``naif_keywords`` (INS-533001_OD_K): read from there, the
    same model as with ``odk`` in the block."""
    isd = _lunar_orbiter_isd()
    model = read_sensor(_write(tmp_path, isd))
    np.testing.assert_allclose(model.distortion.coefficients,
                               [1.2e-5, -0.8e-5, 0.02, -0.015, 1e-6, 2e-9])
    isd["optical_distortion"]["lunarorbiter"]["odk"] = [1e-6, 2e-9]
    twin = read_sensor(_write(tmp_path, isd, "twin.json"))
    lines, samples = _grid(model)
    np.testing.assert_array_equal(model.image_to_ground(lines, samples),
                                  twin.image_to_ground(lines, samples))
    error, hits = _round_trip(model, lines, samples)
    assert hits == lines.size and error <= 0.01


def test_null_focal_length_is_filled_from_naif_keywords(tmp_path):
    """ALE's ISDs made from ISIS labels may carry ``focal_length: null`` with the value in
    ``naif_keywords``; without it there, the ISD is refused saying why."""
    isd = _lunar_orbiter_isd()
    isd["focal_length_model"]["focal_length"] = None
    assert read_sensor(_write(tmp_path, isd)).focal_length == 610.0
    del isd["naif_keywords"]["INS-533001_FOCAL_LENGTH"]
    with pytest.raises(InputError, match="focal_length.*naif_keywords holds no "
                                         "INS<code>_FOCAL_LENGTH"):
        read_sensor(_write(tmp_path, isd, "none.json"))


def test_summing_of_zero_reads_as_one(tmp_path):
    """CaSSIS's summing *mode* 0 (1×1): ISIS's TgoCassisCamera and ALE read it as 1."""
    isd = nadir_isd(10.0, 5.0, 50_000.0, focal_mm=50.0, pitch_mm=0.01, lines=32, samples=32)
    isd["detector_line_summing"] = isd["detector_sample_summing"] = 0
    model = read_sensor(_write(tmp_path, isd))
    assert model.detector.line_summing == model.detector.sample_summing == 1.0


def test_radial_distortion_of_one_coefficient(tmp_path):
    """Galileo SSI's ISD has ``radial`` with one coefficient: the others are zero."""
    isd = nadir_isd(10.0, 5.0, 50_000.0, focal_mm=50.0, pitch_mm=0.01, lines=32, samples=32)
    isd["optical_distortion"] = {"radial": {"coefficients": [-2.5e-5]}}
    model = read_sensor(_write(tmp_path, isd))
    np.testing.assert_array_equal(model.distortion.coefficients, [-2.5e-5, 0.0, 0.0])


def _legacy(isd: dict) -> dict:
    """usgscsm's older layout of an ALE ISD whose body rotation is the identity."""
    out = {k: v for k, v in isd.items()
           if k not in ("instrument_position", "instrument_pointing", "body_rotation")}
    pos, point = isd["instrument_position"], isd["instrument_pointing"]
    centre = isd["center_ephemeris_time"]
    out["sensor_position"] = {k: pos[k] for k in ("positions", "velocities", "unit") if k in pos}
    out["sensor_orientation"] = {"quaternions": [[-x, -y, -z, w] for w, x, y, z
                                                 in point["quaternions"]]}
    times, qtimes = pos["ephemeris_times"], point["ephemeris_times"]
    if len(times) > 1:
        out["t0_ephemeris"] = times[0] - centre
        out["dt_ephemeris"] = (times[-1] - times[0]) / (len(times) - 1)
        out["t0_quaternion"] = qtimes[0] - centre
        out["dt_quaternion"] = (qtimes[-1] - qtimes[0]) / (len(qtimes) - 1)
    sun = dict(isd["sun_position"])
    sun.pop("ephemeris_times", None)
    out["sun_position"] = sun
    return out


def test_older_usgscsm_layout_linescan_matches_usgscsm_1(tmp_path):
    """usgscsm's older layout of its OrbitalLineScan fixture: the equally spaced nodes
    are used as given (no resampling), as usgscsm 1.x did; its published centre point
    (LineScanCameraTests.cpp before ALE's resampling: (999999.67040488799, 0,
    -811.90523782723039))."""
    isd = json.loads((DATA / "orbitalLineScan.json").read_text())
    for key in ("instrument_position", "instrument_pointing", "body_rotation", "sun_position"):
        if isinstance(isd[key], str):
            isd[key] = json.loads(isd[key])
    model = read_sensor(_write(tmp_path, _legacy(isd)))
    assert isinstance(model, LineScanSensor) and len(model.positions) == 16
    np.testing.assert_allclose(model.image_to_ground(8.5, 8.0),
                               (999999.67040488799, 0.0, -811.90523782723039), atol=1e-6)
    error, hits = _round_trip(model, *_grid(model, 9))
    assert hits == 81 and error <= 0.01
    # the corners as the ALE layout of the same fixture sees them (a quaternion read
    # without its conjugation would swap the image's sides: 1.5 km off)
    ale = read_sensor(_write(tmp_path, isd, "ale.json"))
    corners = (np.array([0.5, 0.5, 15.5, 15.5]), np.array([0.5, 15.5, 0.5, 15.5]))
    np.testing.assert_allclose(model.image_to_ground(*corners), ale.image_to_ground(*corners),
                               atol=1.0)


def test_older_usgscsm_layout_frame(tmp_path):
    """usgscsm's older frame layout of its OrbitalFramer fixture: the same centre point
    (FrameCameraTests.cpp: (1e6, 0, 0))."""
    isd = json.loads((DATA / "orbitalFramer.json").read_text())
    model = read_sensor(_write(tmp_path, _legacy(isd)))
    np.testing.assert_allclose(model.image_to_ground(8.0, 8.0), (1e6, 0.0, 0.0), atol=1e-6)
    ale = read_sensor(_write(tmp_path, isd, "ale.json"))
    corners = (np.array([0.5, 0.5, 15.5]), np.array([0.5, 15.5, 0.5]))
    np.testing.assert_allclose(model.image_to_ground(*corners), ale.image_to_ground(*corners),
                               atol=1e-6)


def test_older_layout_without_its_times_is_refused(tmp_path):
    isd = json.loads((DATA / "orbitalLineScan.json").read_text())
    for key in ("instrument_position", "instrument_pointing", "body_rotation", "sun_position"):
        if isinstance(isd[key], str):
            isd[key] = json.loads(isd[key])
    legacy = _legacy(isd)
    del legacy["dt_ephemeris"]
    with pytest.raises(InputError, match="t0_ephemeris' / 'dt_ephemeris"):
        read_sensor(_write(tmp_path, legacy))


def test_negative_line_times_through_the_centre_load(tmp_path):
    """Apollo's panoramic camera: lines timed backwards through the centre time, as
    usgscsm times them; the model closes."""
    sensor = linescan_sensor(lines=120, samples=30, gsd=2.0)
    isd = isd_dict(sensor)
    (line0, t0, dt), = isd["line_scan_rate"]
    isd["line_scan_rate"] = [[line0, -t0, -dt]]  # the first line last
    model = read_sensor(_write(tmp_path, isd))
    assert model.line_time(0.5) > model.line_time(119.5)
    error, hits = _round_trip(model, *_grid(model))
    assert hits == 17 * 17 and error <= 0.01
    # the same image scanned forwards: line l backwards is line (lines − l) forwards
    forward = read_sensor(_write(tmp_path, isd_dict(sensor), "forward.json"))
    np.testing.assert_allclose(model.image_to_ground(10.5, 15.0),
                               forward.image_to_ground(109.5, 15.0), atol=1e-3)


@pytest.mark.parametrize("radii, depth_km, inside", [
    (MARS, 8.0, False),        # Hellas's floor: a camera can be there
    (MARS, 12.0, True),        # deeper than any Mars surface
    ((1737400.0, 1737400.0), 9.0, False),   # the Moon's lowest (−9.1 km)
    ((1737400.0, 1737400.0), 1735.0, True),  # km written as m: 1000× too close
    ((274.0, 138.0), 60.0, False),   # Itokawa-size: its shape is not the ellipsoid
    ((274.0, 138.0), 150.0, True),   # below half its mean radius
])
def test_inside_the_body_is_judged_against_the_relief(radii, depth_km, inside):
    from demtool.sensors.body_view import relief_band

    a, b = radii
    depth = depth_km * 1000.0 if a > 1e5 else depth_km
    height = height_above_ellipsoid(_on_ellipsoid(30.0, 10.0, -depth, a, b), a, b)
    assert (height < relief_band(a, b).low) == inside
