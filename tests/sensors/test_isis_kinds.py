"""ISIS cubes of issue 41: the instrument code of NaifIkCode-only cubes (ISIS
``Spice::init``), MDIS's filter keywords and temperature-dependent focal length, Viking's
focal lengths, THEMIS IR's line-scan timing, and the true reason of each refusal (SAR,
no SPICE, tables named but absent, ISIS2 qube, ring-plane projection, push frame); with
../shared, every cube of the conformance corpus loads and round-trips or is refused for
the reason its README gives."""

from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import read_sensor
from demtool.sensors.base import ray_ellipsoid_intersection
from demtool.sensors.distortion import MODELS, Distortion
from demtool.sensors.isis_label import read_label
from demtool.sensors.isis_linescan import cube_isd
from demtool.sensors.isis_pushframe import marci_isd, wac_isd
from tests.sensors.test_isis_apollo import write_cube
from tests.sensors.test_isis_linescan import CAMERAS, ET0, write_linescan_cube

CONFORMANCE = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "conformance" \
    / "isis" / "isis" / "tests" / "data"

MDIS = {"BODY199_RADII": "(2440.0, 2440.0, 2440.0)",
        "TempDependentFocalLength": "78.2574555656155",
        "INS-236807_FOCAL_LENGTH": "78.2367",
        "INS-236807_FL_TEMP_COEFFS": "(78.286534058671, 0.0010882669556798, 0, 0, 0, 0)",
        "INS-236807_ITRANSS": "(0.0, 71.42857143, 0.0)",
        "INS-236807_ITRANSL": "(0.0, 0.0, 71.42857143)",
        "INS-236800_BORESIGHT_SAMPLE": "512.5", "INS-236800_BORESIGHT_LINE": "512.5",
        "INS-236807_OD_T_X": "(0.0, 0.99998164157363, -5.27602089733654e-06, "
                             "-7.32059999999968e-05, 2.15189999999999e-06, 0.0, "
                             "5.34975284298397e-06, 1.46060238113648e-07, "
                             "5.48634198618427e-06, 1.23834839985695e-07)",
        "INS-236807_OD_T_Y": "(0.0, 5.27602089733571e-06, 0.99998164157363, 0.0, "
                             "-7.3206e-05, 2.15189999999974e-06, -1.23834839985724e-07, "
                             "5.48634198618425e-06, -1.46060238113479e-07, "
                             "5.34975284298432e-06)"}
MDIS_GROUPS = (b"  Group = Instrument\n    InstrumentId = MDIS-WAC\n    TargetName = Mercury\n"
               b"    FocalPlaneTemperature = -26.72 <DEGC>\n    FpuBinningMode = 0\n"
               b"    PixelBinningMode = 0\n  End_Group\n"
               b"  Group = BandBin\n    Number = 7\n  End_Group\n")
VIKING = {"BODY499_RADII": "(3396.19, 3396.19, 3376.2)",
          "INS-30001_ITRANSS": "(0.0, 85.0, 0.0)", "INS-30001_ITRANSL": "(0.0, 0.0, 85.0)"}
VIKING_GROUPS = (b"  Group = Instrument\n    SpacecraftName = VIKING_ORBITER_2\n"
                 b"    InstrumentId = VISUAL_IMAGING_SUBSYSTEM_CAMERA_A\n"
                 b"    TargetName = MARS\n  End_Group\n")


def _edit_label(path, *replacements, head=8192):
    """Replace text in a label-only cube's label, keeping the tables where they are."""
    data = path.read_bytes()
    label = data[:head].rstrip(b"\0")
    for old, new in replacements:
        assert old in label
        label = label.replace(old, new, 1)
    assert len(label) < head
    path.write_bytes(label.ljust(head, b"\0") + data[head:])
    return path


def _round_trip(model):
    """Rays of a 9 × 9 grid that meet the body, and each one's round-trip error: pixels,
    or, where ground → image returns another pixel (overlapping framelets), the distance
    of that pixel's ground from the ray's in ground pixels (GSD)."""
    ll, ss = np.meshgrid(np.linspace(0.5, model.lines - 0.5, 9),
                         np.linspace(0.5, model.samples - 0.5, 9), indexing="ij")
    ll, ss = ll.ravel(), ss.ravel()
    ray = model.image_to_ray(ll, ss)
    xyz, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, *model.radii, 0.0,
                                          return_hit=True)
    ll, ss, xyz = ll[hit], ss[hit], xyz[hit]
    back_l, back_s = model.ground_to_image(xyz)
    error = np.hypot(back_l - ll, back_s - ss)
    far = ~(error <= 0.01)
    if far.any():
        other = model.image_to_ground(back_l[far], back_s[far])
        gsd = np.linalg.norm(model.image_to_ground(ll[far] + 1.0, ss[far]) - xyz[far], axis=-1)
        error[far] = np.linalg.norm(other - xyz[far], axis=-1) / gsd
    return hit, error


def test_mdis_wac_with_naif_ik_code_only_reads_its_filter(tmp_path):
    # MdisCamera: the filter's code −236800 − 7 holds ITRANS and the Taylor distortion,
    # the camera's code the boresight; spiceinit's TempDependentFocalLength is
    # Σ FL_TEMP_COEFFS[i] T^i at T = −26.72 °C.
    path = write_cube(tmp_path / "mdis.cub", size=1024, naif=MDIS, distance_km=2440 + 12000)
    path = _edit_label(path, (b"NaifFrameCode = -915240", b"NaifIkCode = -236800"),
                       (b"  Group = Kernels", MDIS_GROUPS + b"  Group = Kernels"))
    model = read_sensor(path)
    assert model.focal_length == pytest.approx(78.286534058671 + 0.0010882669556798 * -26.72,
                                               abs=1e-9)
    assert model.distortion.model == "transverse"
    assert model.distortion.coefficients[1] == pytest.approx(0.99998164157363)
    assert (model.detector.center_sample, model.detector.center_line) == (512.0, 512.0)
    hit, error = _round_trip(model)
    assert hit.all() and error.max() < 1e-4  # the Taylor inverse's Newton tolerance


def test_viking_focal_length_and_origin_are_viking_cameras(tmp_path):
    path = write_cube(tmp_path / "vik.cub", size=1204, naif=VIKING, distance_km=3396.19 + 2000)
    path = _edit_label(path, (b"NaifFrameCode = -915240", b"NaifFrameCode = -30001"),
                       (b"  Group = Kernels", VIKING_GROUPS + b"  Group = Kernels"))
    model = read_sensor(path)
    assert model.focal_length == 474.610  # VikingCamera, VO2 camera A
    assert (model.detector.center_sample, model.detector.center_line) == (601.5, 527.5)
    assert any("reseau" in note for note in model.notes)
    hit, error = _round_trip(model)
    assert hit.all() and error.max() < 1e-6


def test_themis_ir_timing_and_detector_are_themis_ir_cameras(tmp_path, monkeypatch):
    # ThemisIrCamera: no LineExposureDuration; r = 33.2871 ms × SpatialSumming; start =
    # clock + SpacecraftClockOffset + (d − 0.5) r with filter 3's TDI line d = 50.5;
    # along-track offset 120.5 − d − 0.089, sample origin 160.5 − 0.005 (Kirk's terms).
    monkeypatch.setitem(CAMERAS, "themisir", dict(
        code=-53031, code_key="NaifFrameCode", clock="SpacecraftClockCount",
        instrument={"InstrumentId": "THEMIS_IR", "SpacecraftClockCount": "698713127.000",
                    "SpacecraftClockOffset": "0.5 <seconds>", "TimeDelayIntegration":
                    "ENABLED", "SpatialSumming": 1},
        naif={"INS-53031_ITRANSS": "(0.0, 20.0, 0.0)", "INS-53031_ITRANSL": "(0.0, 0.0, 20.0)"},
        rate=0.0332871, start=ET0))
    path = write_linescan_cube(tmp_path / "thm.cub", "themisir")
    path = _edit_label(path, (b"  Group = Kernels", b"  Group = BandBin\n    FilterNumber = "
                              b"(3, 4)\n  End_Group\n  Group = Kernels"), head=16384)
    isd = cube_isd(path)
    start = ET0 + 0.5 + 50.0 * 0.0332871
    assert isd["starting_ephemeris_time"] == pytest.approx(start + 100.0 * 0.0332871, abs=1e-9)
    assert isd["line_scan_rate"][0][2] == pytest.approx(2 * 0.0332871)  # AlphaCube 2x
    assert isd["detector_center"]["line"] == pytest.approx(-(120.5 - 50.5 - 0.089))
    assert isd["detector_center"]["sample"] == pytest.approx(160.5 - 0.005 - 0.5)
    assert isd["optical_distortion"] == {"themisir": {"p_k": 0.994260, "p_alpha1": 0.00447623,
                                                      "p_alpha2": 0.00107556}}
    assert isd["focal_length_model"]["focal_length"] == 203.9213
    assert "band 1 (filter 3) of 2" in isd["notes"][0]
    if "themisir" not in MODELS:  # ISIS's ThemisIrDistortionMap, from the ISD readers
        with pytest.raises(InputError, match=r"thm\.cub: needs ISIS's distortion map "
                                             r"'themisir', which this demtool lacks"):
            read_sensor(path)


@pytest.mark.parametrize("edit, match", [
    ((b"  Group = Kernels", b"  Group = Instrument\n    InstrumentId = MRFLRO\n  End_Group\n"
      b"  Group = Kernels"), r"x\.cub: is a synthetic-aperture radar image \(MRFLRO"),
    ((b"  Group = Kernels", b"  Group = Instrument\n    InstrumentId = THEMIS_VIS\n"
      b"  End_Group\n  Group = Kernels"), r"x\.cub: is a push-frame cube of THEMIS_VIS"),
    ((b"  Group = Kernels", b"  Group = Mapping\n    ProjectionName = Planar\n"
      b"    TargetName = Saturn\n  End_Group\n  Group = Kernels"),
     r"x\.cub: is a map-projected cube onto the ring plane \(ISIS Mapping group: Planar"),
    ((b"NaifFrameCode = -915240\n", b"NaifFrameCode = -915240\n    InstrumentPointing = "
      b"Table\n"), None),
])
def test_cube_refused_with_its_true_reason(tmp_path, edit, match):
    path = _edit_label(write_cube(tmp_path / "x.cub"), edit)
    if match is None:  # the pointing table is attached: the cube loads
        assert read_sensor(path).focal_length == pytest.approx(76.054)
        return
    with pytest.raises(InputError, match=match) as info:
        read_sensor(path)
    assert "\n" not in str(info.value)


def test_cube_without_spice_or_with_tables_named_but_absent_says_so(tmp_path):
    path = write_cube(tmp_path / "x.cub")
    data = path.read_bytes()
    label = data[:8192].rstrip(b"\0")
    bare = label[:label.index(b"End_Object\nObject = Table")] + b"End_Object\nEnd\n"
    (tmp_path / "raw.cub").write_bytes(bare.ljust(8192, b"\0"))
    with pytest.raises(InputError, match=r"raw\.cub: the cube has no SPICE attached \(the "
                                         r"Kernels group holds only the NAIF code\)"):
        read_sensor(tmp_path / "raw.cub")
    named = bare.replace(b"NaifFrameCode = -915240\n", b"NaifFrameCode = -915240\n"
                         b"    InstrumentPointing = Table\n")
    (tmp_path / "named.cub").write_bytes(named.ljust(8192, b"\0"))
    with pytest.raises(InputError, match=r"named\.cub: the Kernels group names 'Table' for "
                                         r"InstrumentPointing but the file has no "
                                         r"InstrumentPointing table attached"):
        read_sensor(tmp_path / "named.cub")


def test_isis2_qube_is_named(tmp_path):
    path = tmp_path / "lo.cub"
    path.write_bytes(b"CCSD3ZF0000100000001NJPL3IF0PDS200000001 = SFDU_LABEL\n"
                     b"RECORD_TYPE = FIXED_LENGTH\n^QUBE = 9190 <BYTES>\nObject = QUBE\n"
                     b"  AXES = 3\nEnd_Object\nEND\n".ljust(4096, b" "))
    with pytest.raises(InputError, match=r"lo\.cub: is an ISIS2 qube .*lo2isis"):
        read_sensor(path)


# ---------------------------------------------------------------------------------------
# The conformance corpus (../shared): one cube per outcome (bench/conformance.py runs
# them all), as its README states it; slow: each label takes seconds to parse
# ---------------------------------------------------------------------------------------

_NO_SPICE = r"has no SPICE attached \(the Kernels group holds only the NAIF code\)"
REFUSED = {
    "hicubeit/RE.cub": _NO_SPICE,
    "lrowaccal/M1388981421CE.tmp.vis.even.reduced.cub": _NO_SPICE,
    "demprep/vest64_dtm_specialpixels_downsampled.cub":
        r"is a map-projected cube \(ISIS Mapping group: Equirectangular on Vesta",
    "rings/rings1proj.cub": r"is a map-projected cube onto the ring plane",
    "miniRFImage/LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub": r"synthetic-aperture radar",
    "lo2isis/case04/3083_med_isis2_cropped.cub": r"is an ISIS2 qube",
    "tgoCassis/tgocassisstitch/CAS-MCO-2016-11-22T16.16.16.833-RED-01006-B1_crop.cub":
        r"names 'Table' for InstrumentPointing.* but the file has no InstrumentPointing",
}
#: Cubes that load, with where they look (planetocentric lat, lon in degrees, ±1°) when
#: another file confirms it: the Viking and THEMIS images of one control network.
LOADED = {
    "offBodyImage/EW0131773041G.cal.crop.cub": None,
    "vikingThemisNetwork/F704b51.lev1_slo_crop.cub": (44.0, -74.9),
    "vikingThemisNetwork/I52634011RDR_crop.cub": (42.2, -79.6),
}
THEMIS = ("vikingThemisNetwork/I52634011RDR_crop.cub",)


@pytest.mark.slow
@pytest.mark.skipif(not CONFORMANCE.exists(), reason="../shared/data/conformance is absent")
@pytest.mark.parametrize("name", sorted(REFUSED))
def test_conformance_cube_refused_for_its_true_reason(name):
    with pytest.raises(InputError, match=REFUSED[name]) as info:
        read_sensor(CONFORMANCE / name)
    assert "\n" not in str(info.value) and Path(name).name in str(info.value)


@pytest.mark.slow
@pytest.mark.skipif(not CONFORMANCE.exists(), reason="../shared/data/conformance is absent")
@pytest.mark.parametrize("name", sorted(LOADED))
def test_conformance_cube_loads_and_round_trips(name):
    if name in THEMIS and "themisir" not in MODELS:  # ISIS's ThemisIrDistortionMap
        with pytest.raises(InputError, match="themisir"):
            read_sensor(CONFORMANCE / name)
        return
    model = read_sensor(CONFORMANCE / name)
    hit, error = _round_trip(model)
    assert hit.any() and error.max() <= 0.01
    if LOADED[name] is not None:
        xyz = model.image_to_ground(model.lines / 2, model.samples / 2)
        lat = np.degrees(np.arctan2(xyz[2], np.hypot(xyz[0], xyz[1])))
        lon = np.degrees(np.arctan2(xyz[1], xyz[0]))
        assert abs(lat - LOADED[name][0]) < 1.0 and abs(lon - LOADED[name][1]) < 1.0


def test_marci_distortion_is_isis_marci_distortion_map():
    # MarciDistortionMap: in pixels of pitch p, u = d (k0 + k1 r² + k2 r⁴ + k3 r⁶).
    odk, pitch = [0.997322, 2.84786e-06, -6.67752e-12, 1.43076e-16], 0.009
    lens = Distortion("marci", [pitch, *odk])
    x, y = np.array([1.2, -3.0, 0.0]), np.array([0.5, 2.0, 0.0])
    r2 = (x * x + y * y) / pitch ** 2
    factor = odk[0] + odk[1] * r2 + odk[2] * r2 ** 2 + odk[3] * r2 ** 3
    u, v = lens.remove(x, y)
    np.testing.assert_allclose(u, x * factor, rtol=1e-14)
    np.testing.assert_allclose(v, y * factor, rtol=1e-14)
    back_x, back_y = lens.apply(u, v)
    np.testing.assert_allclose(back_x, x, atol=1e-11)
    np.testing.assert_allclose(back_y, y, atol=1e-11)


def test_marci_framelet_timing_and_detector_are_marci_cameras(tmp_path, monkeypatch):
    # MarciCamera: t0 = clock − ExposureDuration / 2000; BLUE's framelet offset 4 ×
    # ColorOffset 2, negated (DataFlipped): −8 framelets, so usgscsm's start (reversed
    # order) is t0 − 8 Δ; BLUE's first detector row 709, origin (512.5, 768.5) ISIS.
    monkeypatch.setitem(CAMERAS, "marci", dict(
        code=-74410, code_key="NaifIkCode", clock="SpacecraftClockCount",
        instrument={"InstrumentId": "Marci", "SpacecraftClockCount": "1235691810:1",
                    "SummingMode": 2, "DataFlipped": 1, "ColorOffset": 2,
                    "InterframeDelay": "2.6 <seconds>", "ExposureDuration": "0.0088 <seconds>",
                    "Framelets": "Even"},
        naif={"INS-74410_FOCAL_LENGTH": 3.9215079, "INS-74410_PIXEL_SIZE": 0.009,
              "INS-74410_DISTORTION_COEFFS": "(0.997322, 2.84786e-06, -6.67752e-12, "
                                             "1.43076e-16)",
              "INS-74400_ITRANSS": "(0.0, 111.11111111111, 0.0)",
              "INS-74400_ITRANSL": "(0.0, 0.0, 111.11111111111)"},
        rate=2.6, start=ET0))
    path = write_linescan_cube(tmp_path / "marci.cub", "marci")
    path = _edit_label(path, (b"  Group = Kernels", b"  Group = BandBin\n    FilterName = "
                              b"(BLUE, GREEN)\n  End_Group\n  Group = Kernels"), head=16384)
    label, data = read_label(path)
    isd, line_offset, line_scale = marci_isd(path, label, data)
    assert isd["starting_ephemeris_time"] == pytest.approx(ET0 - 0.0088 / 2000 - 8 * 2.6,
                                                           abs=1e-9)
    assert isd["framelet_order_reversed"] and not isd["framelets_flipped"]
    assert (isd["framelet_height"], isd["detector_line_summing"]) == (16, 2)
    assert isd["starting_detector_line"] == 709.0 and isd["exposure_duration"] == 0.0
    assert isd["detector_center"] == {"line": 768.0, "sample": 512.0}
    assert isd["image_lines"] == 4000  # the parent image: its framelets
    assert (line_offset, line_scale) == (100.0, 2.0)  # AlphaCube: cube line → parent line
    assert "band 1 (BLUE) of 2" in isd["notes"][0]


@pytest.mark.slow
@pytest.mark.skipif(not CONFORMANCE.exists(), reason="../shared/data/conformance is absent")
def test_marci_cube_sees_its_image_centre_and_framelets_agree():
    # K14_059003_3475_MA_00N112W: the tables cover the whole parent image (10640 lines);
    # its centre line looks at the 00N 112W of the file name.
    model = read_sensor(CONFORMANCE / "marcical/K14_059003_3475_MA_00N112W_cropped.cub")
    xyz = model.image_to_ground(5320.0 - model.line_offset, 128.0)
    lat = np.degrees(np.arctan2(xyz[2], np.hypot(xyz[0], xyz[1])))
    lon = np.degrees(np.arctan2(xyz[1], xyz[0]))
    assert abs(lat) < 3.0 and abs(lon + 112.0) < 3.0
    hit, error = _round_trip(model)  # overlapping framelets: back on the same ground
    assert hit.all() and error.max() <= 0.01


def test_mocwa_distortion_is_isis_moc_wide_angle_distortion_map():
    # MocWideAngleDistortionMap::SetFocalPlane (blue: y scaled by 1.000452).
    c = [1.000452, 1.000246, 0.4612695, 0.2352545, 0.3535922, -0.2853861, 0.5574971]
    focal = 11.20537656
    lens = Distortion("mocwa", c, focal)
    x, y = np.array([1.0, -6.0, 9.5]), np.array([0.5, 2.0, -3.0])
    sy = y / c[0]
    s = np.hypot(x, sy)
    angle = np.arctan(s / focal)
    angle_u = angle * np.polynomial.polynomial.polyval(angle * angle, c[1:])
    u, v = lens.remove(x, y)
    np.testing.assert_allclose(u, x * focal * np.tan(angle_u) / s, rtol=1e-13)
    np.testing.assert_allclose(v, sy * focal * np.tan(angle_u) / s, rtol=1e-13)
    back_x, back_y = lens.apply(u, v)  # the exact inverse (ISIS's second fit is not)
    np.testing.assert_allclose(back_x, x, atol=1e-12)
    np.testing.assert_allclose(back_y, y, atol=1e-12)


def test_moc_wa_timing_and_detector_are_moc_wide_angle_cameras(tmp_path, monkeypatch):
    # MocWideAngleCamera (red): start = clock, r = LineExposureDuration × DowntrackSumming;
    # first detector sample FirstLineSample, summed by CrosstrackSumming; origin sample
    # 1674.65 and along-track offset 6.7785 (ISIS), the red distortion constants.
    monkeypatch.setitem(CAMERAS, "mocwa", dict(
        code=-94032, code_key="NaifFrameCode", clock="SpacecraftClockCount",
        instrument={"InstrumentId": "MOC-WA", "SpacecraftClockCount": "561812335:32",
                    "LineExposureDuration": "100.0 <milliseconds>", "CrosstrackSumming": 4,
                    "DowntrackSumming": 4, "FirstLineSample": 673},
        naif={"INS-94032_FOCAL_LENGTH": 11.20537656,
              "INS-94032_ITRANSS": "(0.0, 0.0, -142.8571429)",
              "INS-94032_ITRANSL": "(0.0, 142.8571429, 0.0)"},
        rate=0.4, start=ET0))
    path = write_linescan_cube(tmp_path / "moc.cub", "mocwa")
    path = _edit_label(path, (b"  Group = Kernels", b"  Group = BandBin\n    FilterName = RED"
                              b"\n  End_Group\n  Group = Kernels"), head=16384)
    isd = cube_isd(path)
    assert isd["starting_ephemeris_time"] == pytest.approx(ET0 + 100.0 * 0.4, abs=1e-9)
    assert isd["line_scan_rate"][0][2] == pytest.approx(2 * 0.4)  # AlphaCube 2x
    assert isd["detector_center"] == {"line": -6.7785, "sample": 1674.15}
    # AlphaCube sample 200.5 (ISIS) is CSM 200: 200 × 4 + 672 detector samples in
    assert isd["starting_detector_sample"] == pytest.approx(200 * 4 + 672)
    assert isd["detector_sample_summing"] == pytest.approx(2 * 4)
    assert isd["optical_distortion"]["mocwa"]["coefficients"][1] == 0.9993258


WAC_NAIF = {"INS-85621_FILTER_BANDCENTER": "(415, 566, 604, 643, 689)",
            "INS-85621_FILTER_OFFSET": "(703, 728, 754, 781, 806)",
            "INS-85621_FILTER_BANDID": "(3, 4, 5, 6, 7)",
            "INS-85621_COLOR_SAMPLE_OFFSET": 160.0,
            "INS-85632_FOCAL_LENGTH": 6.0193387, "INS-85632_BORESIGHT_SAMPLE": 509.5445,
            "INS-85632_BORESIGHT_LINE": 775.7541,
            "INS-85632_ITRANSS": "(0.0, 0.0026684381921, 111.1111110790686)",
            "INS-85632_ITRANSL": "(0.0, -111.1111110790686, 0.0026684381921)",
            "INS-85632_OD_K": "(0.0113301372841102, 0.000147788496863675, "
                              "4.87090732732635e-06)"}


def test_lro_wac_with_naif_ik_code_only_is_lro_wide_angle_camera(tmp_path, monkeypatch):
    # LroWideAngleCamera (VIS, COLOR mode): band 1 is 566 nm, filter id 4 → code
    # −85621 − (7 + 4) = −85632; its first detector row 728 ranks 2nd of the filters'
    # rows, so its framelet offset is 1 × ColorOffset 2; t0 = clock + 60 ms / 2; the
    # detector origin is BORESIGHT + 1 (ISIS), CSM BORESIGHT + 0.5; the first detector
    # sample COLOR_SAMPLE_OFFSET + 1 (ISIS), CSM 160.
    monkeypatch.setitem(CAMERAS, "wac", dict(
        code=-85621, code_key="NaifIkCode", clock="SpacecraftClockStartCount",
        instrument={"InstrumentId": "WAC-VIS", "SpacecraftClockStartCount": "1/656034953:43889",
                    "ExposureDuration": "60.0 <ms>", "InterframeDelay": "10.0 <ms>",
                    "DataFlipped": "No", "ColorOffset": 2, "Mode": 0,
                    "InstrumentModeId": "COLOR", "Framelets": "Even"},
        naif=WAC_NAIF, rate=0.01, start=ET0))
    path = write_linescan_cube(tmp_path / "wac.cub", "wac")
    path = _edit_label(path, (b"  Group = Kernels", b"  Group = BandBin\n    Center = (566, "
                              b"604)\n  End_Group\n  Group = Kernels"), head=16384)
    label, data = read_label(path)
    isd, line_offset, line_scale = wac_isd(path, label, data)
    assert isd["starting_ephemeris_time"] == pytest.approx(ET0 + 0.03 - 2 * 0.01, abs=1e-9)
    assert isd["focal_length_model"]["focal_length"] == 6.0193387
    assert isd["detector_center"] == {"line": 775.7541 + 0.5, "sample": 509.5445 + 0.5}
    assert isd["starting_detector_line"] == 728.0
    assert isd["starting_detector_sample"] == pytest.approx(160.0 + 200.0)  # + AlphaCube
    assert (isd["framelet_height"], isd["detector_line_summing"]) == (14, 1)
    assert not isd["framelet_order_reversed"]
    assert isd["optical_distortion"]["lrowac"]["coefficients"][0] == 0.0113301372841102
    model = read_sensor(path)
    hit, error = _round_trip(model)
    assert hit.all() and error.max() <= 0.01


def test_lrowac_distortion_is_isis_lro_wide_angle_distortion_map():
    k = [0.0113301372841102, 0.000147788496863675, 4.87090732732635e-06]
    lens = Distortion("lrowac", k)
    x, y = np.array([1.0, -3.5, 4.0]), np.array([0.5, 2.0, -4.5])
    rr = x * x + y * y
    factor = 1 + k[0] * rr + k[1] * rr ** 2 + k[2] * rr ** 3
    u, v = lens.remove(x, y)
    np.testing.assert_allclose(u, x * factor, rtol=1e-14)
    back_x, back_y = lens.apply(u, v)
    np.testing.assert_allclose(back_x, x, atol=1e-11)
    np.testing.assert_allclose(back_y, y, atol=1e-11)


def test_cassis_distortion_is_isis_tgo_cassis_distortion_map():
    # TgoCassisDistortionMap::SetFocalPlane: u = (A1·χ, A2·χ) / A3·χ, χ = (x², xy, y², x,
    # y, 1) in mm, on the CCD (±10.24 + 0.2 mm); the identity off it.
    a1 = [0.0037613053094827, -0.013415415606581, -1.86749521007237e-05, 1.0002135268184,
          -0.000432362371703953, -0.000948065735350123]
    a2 = [9.9842559363676e-05, 0.0037354370795816, -0.013329991887393,
          -0.000215311328389359, 0.99529601553729, -0.018354271771078]
    a3 = [-3.13320167004204e-05, -7.35655125749807e-06, -1.57664245066771e-05,
          0.0037354946543915, -0.014167194693093, 1.0]
    lens = Distortion("cassis", [10.24, 10.24, *a1, *a2, *a3], 880.0)
    x, y = np.array([5.0, -9.0, 12.0]), np.array([-3.0, 8.0, 1.0])
    chi = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    u, v = lens.remove(x, y)
    np.testing.assert_allclose(u[:2], (np.array(a1) @ chi / (np.array(a3) @ chi))[:2],
                               rtol=1e-14)
    np.testing.assert_allclose(v[:2], (np.array(a2) @ chi / (np.array(a3) @ chi))[:2],
                               rtol=1e-14)
    assert (u[2], v[2]) == (12.0, 1.0)  # off the CCD
    back_x, back_y = lens.apply(u, v)
    np.testing.assert_allclose(back_x, x, atol=1e-11)
    np.testing.assert_allclose(back_y, y, atol=1e-11)
