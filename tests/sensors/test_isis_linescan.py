"""ISIS line-scan cubes (LRO NAC, MRO CTX, MRO HiRISE) read into LineScanSensor models
(demtool.sensors.isis_linescan): synthetic cubes written here, with a known orbit and
attitude, checked against ISIS's timing and detector formulas computed independently;
bad input in one line; and, when ../shared is present, the real cubes against ISIS's
published lronacpho expectation and the 0.01 px round trip."""

import struct
from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import read_sensor
from demtool.sensors.base import matrix_to_quaternion
from demtool.sensors.isis_linescan import read_linescan_cube

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "sensors"
R_KM, H_KM = 3396.19, 300.0
OMEGA = 3.4 / (R_KM + H_KM)  # rad/s: a circular equatorial orbit at 3.4 km/s
ET0 = 300000000.123456789  # ET of the clock count (spiceinit's CLOCK_ET_..._COMPUTED)
ALPHA = {"AlphaSamples": 5000, "AlphaLines": 4000, "AlphaStartingSample": 200.5,
         "AlphaStartingLine": 100.5, "AlphaEndingSample": 600.5, "AlphaEndingLine": 300.5,
         "BetaSamples": 200, "BetaLines": 100}  # a 2x reduced window
CAMERAS = {
    # ISIS MroCtxCamera: start = clock(SpacecraftClockCount), r = LineExposureDuration.
    "ctx": dict(code=-74021, code_key="NaifFrameCode", clock="SpacecraftClockCount",
                instrument={"InstrumentId": "CTX", "LineExposureDuration": "1.880 <MSEC>",
                            "SpacecraftClockCount": "0912345678:123",
                            "SampleFirstPixel": 10, "SpatialSumming": 2},
                naif={"INS-74021_FOCAL_LENGTH": 352.9271664,
                      "INS-74021_ITRANSS": "(0.0, 0.0, 142.85714285714)",
                      "INS-74021_ITRANSL": "(0.0, 142.85714285714, 0.0)",
                      "INS-74021_BORESIGHT_SAMPLE": 400.5, "INS-74021_BORESIGHT_LINE": 0.0,
                      "INS-74021_OD_K": "(-0.0073433925920055, 2.83758786362417e-05, "
                                        "1.28419891240271e-08)"},
                rate=1.88e-3, start=ET0, pitch=1 / 142.85714285714, boresight=400.0,
                focal=352.9271664),
    # ISIS LroNarrowAngleCamera: start = clock(preroll) + offset + preroll · r,
    # r = LineExposureDuration · (1 + MULTIPLI_LINE_ERROR) + ADDITIVE_LINE_ERROR.
    "lronac": dict(code=-85600, code_key="NaifFrameCode", clock="SpacecraftClockPrerollCount",
                   instrument={"InstrumentId": "NACL", "LineExposureDuration": "0.363200 <ms>",
                               "SpacecraftClockPrerollCount": "1/311000799:63569",
                               "SampleFirstPixel": 10, "SpatialSumming": 1},
                   naif={"INS-85600_FOCAL_LENGTH": 699.62,
                         "INS-85600_ITRANSS": "(0.0, 0.0, 142.857)",
                         "INS-85600_ITRANSL": "(0.0, 142.857, 0.0)",
                         "INS-85600_BORESIGHT_SAMPLE": 400.5, "INS-85600_BORESIGHT_LINE": 0.0,
                         "INS-85600_OD_K": 1.81e-05, "INS-85600_CONSTANT_TIME_OFFSET": 0.002,
                         "INS-85600_ADDITIONAL_PREROLL": 1024.0,
                         "INS-85600_ADDITIVE_LINE_ERROR": 1e-7,
                         "INS-85600_MULTIPLI_LINE_ERROR": 0.0045},
                   rate=0.3632e-3 * 1.0045 + 1e-7, start=ET0 + 0.002 + 1024 * (0.3632e-3 * 1.0045
                                                                          + 1e-7),
                   pitch=1 / 142.857, boresight=400.0, focal=699.62),
    # ISIS HiriseCamera: u = (74 + DeltaLineTimerCount / 16) µs, r = u · Summing,
    # start = clock(SpacecraftClockStartCount) − u (Tdi/2 − 0.5) + u (Summing/2 − 0.5);
    # the CCD's affine (CpmmNumber 5 → CCD 4 → INS-74604) about ISIS's detector origin,
    # sample 1024.5 (1-based): y = 0 at centred sample −624, detector sample CSM 400.
    "hirise": dict(code=-74699, code_key="NaifIkCode", clock="SpacecraftClockStartCount",
                   instrument={"InstrumentId": "HIRISE", "LineExposureDuration": "1 <ms>",
                               "SpacecraftClockStartCount": "932977222:01951",
                               "DeltaLineTimerCount": 69, "Tdi": 128, "Summing": 1,
                               "CpmmNumber": 5, "ChannelNumber": 1},
                   naif={"INS-74699_FOCAL_LENGTH": 11994.9988,
                         "INS-74604_ITRANSS": "(-624.0, 0.0, 83.3333)",
                         "INS-74604_ITRANSL": "(0.0, 83.3333, 0.0)",
                         "INS-74699_OD_K": "(-0.0048509, 2.41312e-07, -1.62369e-13)"},
                   rate=78.3125e-6, start=ET0 - 78.3125e-6 * 63.5, pitch=1 / 83.3333,
                   boresight=400.0, focal=11994.9988),
    # MGS MOC-NA, the old label layout (ASP's E1701676.reduce.cub): no NaifKeywords, no
    # computed clock, per-line tables (one record per parent line edge) without frames;
    # the IK's constants (f 3500 mm, 0.013124 mm pixels, origin sample 1024.5) in the reader.
    "moc": dict(code=-94031, code_key="NaifFrameCode", clock=None, old_layout=True,
                instrument={"InstrumentId": "MOC-NA", "LineExposureDuration":
                            "0.723100 <milliseconds>", "SpacecraftClockCount": "709668740:79",
                            "CrosstrackSumming": 2, "DowntrackSumming": 2,
                            "FirstLineSample": 1},
                naif={}, rate=0.7231e-3 * 2, start=ET0, pitch=0.0131240578522949,
                boresight=1024.0, focal=3500.0),
}


def _pose(t):
    """Position (km, J2000 = body frame) and J2000 → camera matrix at ET ``t``: the
    camera's z radial, x along track, y across (the detector's sample axis)."""
    a = OMEGA * (np.asarray(t, dtype=np.float64) - ET0)
    radial = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    along = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], axis=-1)
    across = np.cross(radial, along)
    return (R_KM + H_KM) * radial, OMEGA * (R_KM + H_KM) * along, \
        np.stack([along, across, radial], axis=-2)


def _table(name, fields, rows, start, extra=""):
    rows = np.asarray(rows, dtype="<f8")
    text = (f"Object = Table\n  Name = {name}\n  StartByte = {start}\n  Records = {len(rows)}\n"
            f"  Bytes = {rows.nbytes}\n  ByteOrder = Lsb\n{extra}"
            + "".join(f"  Group = Field\n    Name = {f}\n    Type = Double\n    Size = 1\n"
                      "  End_Group\n" for f in fields) + "End_Object\n")
    return text, rows.tobytes()


def write_linescan_cube(path, camera="ctx", *, drop_naif=(), tables=None, naif=True,
                        clock=True):
    """A label-only ISIS line-scan cube of ``camera`` (``CAMERAS``) with SPICE attached."""
    cam = CAMERAS[camera]
    t = cam["start"] + np.linspace(-1.0, 0.5 + 250 * cam["rate"] * 2, 301)
    pos_t = t[[0, 150, 300]]
    if cam.get("old_layout"):  # one record per parent line edge, all tables
        t = pos_t = cam["start"] + cam["rate"] * np.arange(ALPHA["AlphaLines"] + 1)
        naif, clock = False, False
    quat = matrix_to_quaternion(_pose(t)[2])[:, [3, 0, 1, 2]]
    pos, vel, _ = _pose(pos_t)
    quat_fields = ["J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3", "ET"]
    xyz = ["J2000X", "J2000Y", "J2000Z", "J2000XV", "J2000YV", "J2000ZV", "ET"]
    specs = {"InstrumentPointing": (quat_fields, np.column_stack([quat, t]),
                                    "" if cam.get("old_layout") else
                                    "  TimeDependentFrames = (-74000, 1)\n"
                                    "  ConstantRotation = (1, 0, 0, 0, 1, 0, 0, 0, 1)\n"),
             "InstrumentPosition": (xyz, np.column_stack([pos, vel, pos_t]), ""),
             "BodyRotation": (quat_fields, [[1, 0, 0, 0, v] for v in t[[0, -1]]], ""),
             "SunPosition": (xyz, [[2.2e8, 0, 1e7, 0, 0, 0, v] for v in t[[0, -1]]], "")}
    head, objects, blobs = 16384, [], b""
    for name in (tables if tables is not None else specs):
        text, blob = _table(name, *specs[name][:2], head + 1 + len(blobs), specs[name][2])
        objects.append(text)
        blobs += blob
    keys = {"BODY499_RADII": f"({R_KM}, {R_KM}, {R_KM})", **cam["naif"]}
    if clock and cam["clock"]:
        count = cam["instrument"][cam["clock"]]
        keys[f"CLOCK_ET_-74_{count}_COMPUTED"] = struct.pack("<d", ET0).hex()
    keys = {k: v for k, v in keys.items() if k not in drop_naif}
    naif_text = ("Object = NaifKeywords\n" + "".join(f"  {k} = {v}\n" for k, v in keys.items())
                 + "End_Object\n") if naif else ""
    label = ("Object = IsisCube\n  Object = Core\n    StartByte = 1\n    Group = Dimensions\n"
             f"      Samples = {ALPHA['BetaSamples']}\n      Lines = {ALPHA['BetaLines']}\n"
             "      Bands = 1\n    End_Group\n  End_Object\n  Group = Instrument\n"
             + "".join(f"    {k} = {v}\n" for k, v in cam["instrument"].items())
             + "    TargetName = Mars\n  End_Group\n"
             f"  Group = Kernels\n    {cam['code_key']} = {cam['code']}\n  End_Group\n"
             "  Group = AlphaCube\n" + "".join(f"    {k} = {v}\n" for k, v in ALPHA.items())
             + "  End_Group\nEnd_Object\n" + "".join(objects) + naif_text + "End\n").encode()
    assert len(label) < head
    path.write_bytes(label + b"\0" * (head - len(label)) + blobs)
    return path


def _undistorted(camera, y):
    """ISIS's distortion maps: distorted → undistorted cross-track focal-plane mm."""
    if camera == "lronac":  # LroNarrowAngleDistortionMap
        return y / (1.0 + 1.81e-05 * y * y)
    if camera == "moc":  # CameraDistortionMap without coefficients
        return y
    k = [float(v) for v in CAMERAS[camera]["naif"][
        "INS-74021_OD_K" if camera == "ctx" else "INS-74699_OD_K"].strip("()").split(",")]
    r2 = y * y  # CameraDistortionMap: u = d (1 − (k0 + k1 r² + k2 r⁴)), here x = 0
    return y * (1.0 - (k[0] + k[1] * r2 + k[2] * r2 * r2))


@pytest.mark.parametrize("camera", sorted(CAMERAS))
def test_cube_lines_and_samples_are_isis_timing_and_detector(tmp_path, camera):
    cam = CAMERAS[camera]
    model = read_sensor(write_linescan_cube(tmp_path / f"{camera}.cub", camera))
    assert model.kind == "linescan" and (model.lines, model.samples) == (100, 200)
    assert model.body_name == "Mars"
    assert model.body_naif_id == (None if camera == "moc" else 499)  # MOC: no NaifKeywords
    line = np.array([0.0, 0.5, 37.25, 99.5, 100.0])
    # ISIS: parent (alpha) line L = AlphaStartingLine + 2 c (1-based, c the CSM cube line),
    # exposed at start + (L − 0.5) r.
    times = cam["start"] + (100.5 + 2.0 * line - 0.5) * cam["rate"]
    # Parent sample p = 200.5 + 2 s; ISIS CameraDetectorMap: detector sample = (p − 1) m +
    # m/2 + 0.5 + first (1-based, m the summing), so the CSM detector sample is
    # (200 + 2 s) m + first; the boresight sample is CSM 400.
    first = {"ctx": 10.0, "lronac": 10.0, "hirise": 0.0, "moc": 0.0}[camera]
    m = {"ctx": 2.0, "lronac": 1.0, "hirise": 1.0, "moc": 2.0}[camera]
    bore = ((cam["boresight"] - first) / m - 200.0) / 2.0
    position = _pose(times)[0] * 1000.0
    nadir = position / np.linalg.norm(position, axis=-1)[:, None] * R_KM * 1000.0
    ground = model.image_to_ground(line, np.full(line.shape, bore))
    np.testing.assert_allclose(ground, nadir, atol=2e-3)  # 2 mm; one line is ~6 m here
    np.testing.assert_allclose(model.camera_center(line), position, atol=1e-3)
    # Off the boresight, the ray leaves the nadir by atan(undistorted y / f).
    sample = np.array([0.0, 20.5, 150.0, 200.0])
    ray = model.image_to_ray(np.full(sample.shape, 37.25), sample)
    down = -_pose(cam["start"] + (100.5 + 74.5 - 0.5) * cam["rate"])[0]
    down /= np.linalg.norm(down)
    y = ((200.0 + 2.0 * sample) * m + first - cam["boresight"]) * cam["pitch"]
    want = np.degrees(np.arctan(np.abs(_undistorted(camera, y)) / cam["focal"]))
    got = np.degrees(np.arccos(np.clip(ray.direction @ down, -1, 1)))
    np.testing.assert_allclose(got, want, atol=1e-8)
    # and back: image → ground → image
    ll, ss = np.meshgrid(np.linspace(0.5, 99.5, 5), np.linspace(0.5, 199.5, 5), indexing="ij")
    back = model.ground_to_image(model.image_to_ground(ll, ss))
    assert np.max(np.hypot(back[0] - ll, back[1] - ss)) < 1e-6


@pytest.mark.parametrize("change, match", [
    (dict(drop_naif=("INS-74021_OD_K",)), r"ctx\.cub: NaifKeywords lacks the key "
                                          r"'INS-74021_OD_K'"),
    (dict(clock=False), r"ctx\.cub: NaifKeywords lacks the key "
                        r"'CLOCK_ET_<sc>_0912345678:123_COMPUTED'"),
    (dict(naif=False), r"ctx\.cub: the cube has no NaifKeywords object \(needed: "
                       r"'INS-74021_FOCAL_LENGTH'\)"),
    (dict(tables=("InstrumentPointing", "BodyRotation", "SunPosition")),
     r"ctx\.cub: the cube has no InstrumentPosition table"),
])
def test_cube_missing_a_key_is_refused_in_one_line(tmp_path, change, match):
    path = write_linescan_cube(tmp_path / "ctx.cub", "ctx", **change)
    with pytest.raises(InputError, match=match) as info:
        read_sensor(path)
    assert "\n" not in str(info.value)


def test_line_scan_camera_not_modelled_is_refused_naming_it(tmp_path):
    path = write_linescan_cube(tmp_path / "moc.cub", "ctx")
    data = path.read_bytes().replace(b"NaifFrameCode = -74021", b"NaifFrameCode = -94031")
    path.write_bytes(data.replace(b"InstrumentId = CTX", b"InstrumentId = MOC-NA"))
    with pytest.raises(InputError, match=r"moc\.cub: is a line-scan cube of MOC-NA \(NAIF "
                                         r"code -94031\).*ALE ISD"):
        read_sensor(path)


def test_old_layout_moc_cube_with_tables_not_per_line_is_refused(tmp_path):
    path = write_linescan_cube(tmp_path / "moc.cub", "moc")
    data = path.read_bytes()  # say the parent image has one line more than the tables
    path.write_bytes(data.replace(b"AlphaLines = 4000", b"AlphaLines = 4001"))
    with pytest.raises(InputError, match=r"moc\.cub: the old-layout MOC cube's "
                                         r"InstrumentPointing table \(4001 records, spacing "
                                         r"0\.00144\d* s\) is not one record per edge of its "
                                         r"4001 lines"):
        read_sensor(path)


def test_clock_outside_the_tables_is_refused(tmp_path):
    path = write_linescan_cube(tmp_path / "late.cub", "ctx")
    hexed = struct.pack("<d", ET0).hex().encode()
    path.write_bytes(path.read_bytes().replace(hexed, struct.pack("<d", ET0 + 60).hex().encode()))
    with pytest.raises(InputError, match=r"late\.cub: the image's first line \(ET .*lies "
                                         r"outside the InstrumentPointing table"):
        read_sensor(path)


# -- with ../shared ------------------------------------------------------------------------

LRO_NAC = SHARED / "isis_cubes" / "M143947267L.cal.echo.crop.cub"


@pytest.mark.data
@pytest.mark.skipif(not LRO_NAC.exists(), reason="../shared/data/sensors is absent")
def test_lro_nac_cube_matches_isis_photometry_expectation():
    """ISIS's FunctionalTestsLronacpho (isis/tests/FunctionalTestsLronacpho.cpp, usedem=no)
    expects 0.26584613 ± 0.002 at ISIS line 300, sample 301 of this cube, from the LROC
    empirical function of the incidence, emission and phase angles that the test's comment
    writes out; those angles here come from our camera and sun at that pixel."""
    import warnings

    import rasterio

    model = read_sensor(LRO_NAC)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the cube has no geotransform
        with rasterio.open(LRO_NAC) as src:
            value = float(src.read(1)[299, 300])
    line, sample = np.array([299.5]), np.array([300.5])
    ground = model.image_to_ground(line, sample)[0]
    normal = ground / np.linalg.norm(ground)
    to_cam = model.camera_center(line)[0] - ground
    to_sun = model.sun_position(line)[0] - ground
    ci = normal @ to_sun / np.linalg.norm(to_sun)
    ce = normal @ to_cam / np.linalg.norm(to_cam)
    phase = np.degrees(np.arccos(to_cam @ to_sun / np.linalg.norm(to_cam)
                                 / np.linalg.norm(to_sun)))
    corrected = value * (ci + ce) / ci / np.exp(
        -1.479654495 - 0.000083528 * phase ** 2 + 0.012964707 * phase
        - 0.237774774 * np.sqrt(phase) + 0.556075496 * ce + 0.663671460 * ci
        - 0.439918609 * ci ** 2) * 0.087598
    assert corrected == pytest.approx(0.26584613, abs=0.002)
    lat = np.degrees(np.arcsin(normal[2]))
    lon = np.degrees(np.arctan2(normal[1], normal[0])) % 360
    assert (lat, lon) == pytest.approx((35.98, 102.60), abs=0.01)  # data README: 36.0 N 102.6 E


MOC = SHARED / "isis_cubes" / "E1701676.reduce.cub"


@pytest.mark.data
@pytest.mark.skipif(not MOC.exists(), reason="../shared/data/sensors is absent")
def test_old_layout_moc_cube_sees_north_meridiani():
    """The label's RationaleDesc: "Crater and ejecta with light-toned layer outcrops north
    Meridiani"; MOC-NA's 1.4 m pixels, summed 2 × 2 and reduced 3 ×, from ~390 km."""
    model = read_sensor(MOC)
    assert any("moc20.ti" in note for note in model.notes)
    ground = model.image_to_ground(np.array([462.0]), np.array([171.0]))[0]
    lat = np.degrees(np.arcsin(ground[2] / np.linalg.norm(ground)))
    lon = np.degrees(np.arctan2(ground[1], ground[0]))
    assert -1.0 < lat < 5.0 and 0.0 < lon < 6.0  # Meridiani Planum, north of its centre
    across = np.linalg.norm(model.image_to_ground(462.0, 172.0) - model.image_to_ground(
        462.0, 171.0))
    assert 8.0 < across < 10.0  # ≈ 1.43 m · 2 · 3 at 18° emission


@pytest.mark.data
@pytest.mark.parametrize("name", ["isis_cubes/M143947267L.cal.echo.crop.cub",
                                  "isis_cubes/E1701676.reduce.cub",
                                  "isis_cubes/ctxTestImage.cub",
                                  "hirise_mapprojected/ESP_014038_1415_RED0.30421_33069."
                                  "boulder_shift.before.cub",
                                  "hirise_mapprojected/ESP_031022_1415_RED1.34517_37165."
                                  "boulder_shift.after.cub"])
def test_shared_line_scan_cubes_round_trip(name):
    path = SHARED / name
    if not path.exists():
        pytest.skip("../shared/data/sensors is absent")
    model = read_linescan_cube(path, mapped=True)
    ll, ss = np.meshgrid(np.linspace(0.5, model.lines - 0.5, 5),
                         np.linspace(0.5, model.samples - 0.5, 5), indexing="ij")
    back = model.ground_to_image(model.image_to_ground(ll, ss))
    assert np.max(np.hypot(back[0] - ll, back[1] - ss)) < 0.01


# -- cam2map cubes: the map-projected route (demtool.sensors.isis_cam2map) ------------------

MAPPING = ("  Group = Mapping\n    ProjectionName = Equirectangular\n"
           "    CenterLongitude = 224.0\n    TargetName = Mars\n"
           "    EquatorialRadius = 3396190.0 <meters>\n    PolarRadius = 3376200.0 <meters>\n"
           "    LatitudeType = Planetocentric\n    CenterLatitude = -38.0\n"
           "    PixelResolution = 0.25 <meters/pixel>\n  End_Group\n")


def cam2map_cube(path, camera="ctx"):
    """A label-only cube as cam2map leaves it: the camera's tables and a Mapping group."""
    path = write_linescan_cube(path, camera)
    path.write_bytes(_insert_mapping(path.read_bytes()))
    return path


def _insert_mapping(data: bytes) -> bytes:
    head = 16384
    label = data[:head].rstrip(b"\0").replace(b"  Group = AlphaCube",
                                               MAPPING.encode() + b"  Group = AlphaCube", 1)
    return label.ljust(head, b"\0") + data[head:]


def test_cam2map_cube_camera_is_the_raw_image_of_its_alpha_cube(tmp_path):
    from demtool.sensors.isis_cam2map import cam2map_camera, is_cam2map_cube

    path = cam2map_cube(tmp_path / "map.cub")
    assert is_cam2map_cube(path) and not is_cam2map_cube(write_linescan_cube(
        tmp_path / "raw.cub"))
    with pytest.raises(InputError, match=r"map\.cub: is a map-projected cube \(ISIS Mapping "
                                         r"group: Equirectangular on Mars, 0\.25 m/px\)"):
        read_sensor(path)
    model = cam2map_camera(path)
    raw = read_sensor(tmp_path / "raw.cub")
    assert (model.lines, model.samples) == (100, 200)  # BetaLines, BetaSamples
    np.testing.assert_allclose(model.image_to_ground(37.5, 20.5), raw.image_to_ground(37.5, 20.5))


def test_cam2map_pair_is_an_ortho_pair(tmp_path):
    from types import SimpleNamespace

    from demtool.mapproject.stereo import is_ortho_pair

    left = SimpleNamespace(tags={}, path=cam2map_cube(tmp_path / "a.cub"))
    right = SimpleNamespace(tags={}, path=cam2map_cube(tmp_path / "b.cub"))
    raw = SimpleNamespace(tags={}, path=write_linescan_cube(tmp_path / "raw.cub"))
    assert is_ortho_pair(left, right)
    assert not is_ortho_pair(left, raw) and not is_ortho_pair(raw, right)


def test_cam2map_surface_is_the_label_ellipsoid_above_the_crs_sphere(tmp_path):
    from pyproj import CRS

    from demtool.sensors.isis_cam2map import cam2map_surface

    a, b, radius = 3396190.0, 3376200.0, 3388546.86869391  # GDAL's local radius at −38.07°
    crs = CRS.from_proj4(f"+proj=eqc +lat_ts=-38.0 +lon_0=224 +R={radius} +units=m +type=crs")
    path = cam2map_cube(tmp_path / "map.cub")
    heights, surface = cam2map_surface(path, crs)
    assert surface == "isis-ellipsoid: cam2map's ellipsoid (3396190.0, 3376200.0 m)"
    data = path.read_bytes()  # cam2map on a DEM: the DEM is named, not carried
    shape = b"    ShapeModel = $base/dems/molaMarsPlanetaryRadius0005.cub\n"
    path.write_bytes(data[:16384].rstrip(b"\0").replace(
        b"  Group = Kernels\n", b"  Group = Kernels\n" + shape, 1).ljust(16384, b"\0")
        + data[16384:])
    assert cam2map_surface(path, crs)[1] == (
        "isis-ellipsoid: the Mapping group's ellipsoid (3396190.0, 3376200.0 m); cam2map's "
        "shape model molaMarsPlanetaryRadius0005.cub is not in the cube, heights are "
        "relative to the ellipsoid")
    for lat in (-38.0, 0.0, 60.0):
        y = np.radians(lat) * radius  # eqc: y = R φ
        phi = np.radians(lat)
        r = a * b / np.hypot(b * np.cos(phi), a * np.sin(phi))
        assert float(heights(np.array([0.0]), np.array([y]))[0]) == pytest.approx(r - radius,
                                                                                abs=1e-6)
    assert heights(np.array([0.0]), np.array([0.0]))[0] == pytest.approx(a - radius)


class _Pinhole:
    """A duck-typed model: camera centre fixed, any point is seen (for the precision)."""

    def __init__(self, centre):
        self.centre = np.asarray(centre, dtype=np.float64)

    def ground_to_image(self, xyz):
        return np.zeros(len(xyz)), np.zeros(len(xyz))

    def camera_center(self, line):
        return np.broadcast_to(self.centre, np.shape(line) + (3,))


def test_parallax_precision_is_height_over_base():
    from demtool.sensors.isis_cam2map import parallax_precision

    base, height = 20e3, 280e3  # a symmetric pair over the point: B/H = 1/14
    found = parallax_precision(_Pinhole([-base / 2, 0, height]), _Pinhole([base / 2, 0, height]),
                               np.zeros(3))
    assert found["convergence_deg"] == pytest.approx(np.degrees(2 * np.arctan(base / 2 / height)))
    assert found["height_per_px_parallax_factor"] == pytest.approx(height / base)


HIRISE = SHARED / "hirise_mapprojected"


@pytest.mark.data
@pytest.mark.skipif(not HIRISE.exists(), reason="../shared/data/sensors is absent")
def test_hirise_pair_cameras_see_their_common_map():
    """cam2map filled both maps, so some surface height puts the map's centre inside both
    raw images; ISIS HiriseCamera's detector origin (sample 1024.5) gives one (from about
    −1.3 km up), ALE's origin (0, 0) none (the samples move by 1024)."""
    from demtool.dem.inputs import read_ortho
    from demtool.maps import map_to_xyz, to_pyproj_crs

    left = read_ortho(HIRISE / "ESP_014038_1415_RED0.30421_33069.boulder_shift.before.cub",
                      what="left")
    right = read_ortho(HIRISE / "ESP_031022_1415_RED1.34517_37165.boulder_shift.after.cub",
                       what="right")
    crs, t = to_pyproj_crs(left.info.crs), left.info.transform
    x, y = np.array([t.c + 306 * t.a]), np.array([t.f + 342 * t.e])
    both = []
    for h in np.arange(-8000.0, 8001.0, 250.0):
        xyz = map_to_xyz(crs, x, y, left.heights(x, y) + h)
        inside = [(0 <= ln[0] <= m.lines) and (0 <= sm[0] <= m.samples)
                  for m in (left.sensor, right.sensor) for ln, sm in [m.ground_to_image(xyz)]]
        both.append(all(inside))
    assert any(both)


def test_frame_reader_refuses_a_line_scan_cube_naming_the_reader(tmp_path):
    from demtool.sensors.isis import read_cube

    with pytest.raises(InputError, match=r"ctx\.cub: is a line-scan camera cube \(CTX, "
                                         r"LineExposureDuration 1\.88 MSEC\), not a frame "
                                         r"camera: read it with demtool\.sensors\.read_sensor"):
        read_cube(write_linescan_cube(tmp_path / "ctx.cub"))
