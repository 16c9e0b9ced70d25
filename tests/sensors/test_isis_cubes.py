"""ISIS cubes of issue 24: OSIRIS-REx TAGCAMS (ISIS OsirisRexTagcamsDistortionMap, a body
PROJ lacks), map-projected and line-scan cubes refused in one line, image cubes never
taken for DEMs; with ../shared, ISIS's own NavCam expectations."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import Distortion, read_sensor
from demtool.sensors.isis import read_cube
from demtool.sensors.isis_map import refuse_image_as_dem
from tests.sensors.test_isis_apollo import write_cube

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "sensors"

# OpenCV coefficients of the NavCam IK's size, on a 2.2 µm, 7.64 mm camera.
K = [-0.53766, 0.37526, -0.18368, 0.01, -0.002, 0.0005]
P = [0.00023432, 0.00090875]
PITCH, FOCAL = 0.0022, 7.64


def test_opencv_model_is_opencvs_rational_model():
    # Normalised ray (x', y') = (u/f, −v/f); OpenCV projects it with fx, fy, cx, cy to
    # the distorted pixel; the model gives focal mm, pixel = origin + (x, −y) / pitch.
    fx, fy, cx, cy, origin = 3473.26, 3473.321, 1269.083, 950.747, (1268.5, 950.2)
    c = K + P + [fx * PITCH / FOCAL, fy * PITCH / FOCAL, (cx - origin[0]) * PITCH,
                 -(cy - origin[1]) * PITCH]
    lens = Distortion("opencv", c, FOCAL)
    rng = np.random.default_rng(1)
    u, v = rng.uniform(-2.0, 2.0, (2, 200))  # undistorted focal plane, mm
    x, y = lens.apply(u, v)
    pts = np.column_stack([u / FOCAL, -v / FOCAL, np.ones_like(u)])
    want, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3),
                                np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]),
                                np.array([K[0], K[1], P[0], P[1], K[2], K[3], K[4], K[5]]))
    want = want.reshape(-1, 2)
    np.testing.assert_allclose(origin[0] + x / PITCH, want[:, 0], atol=1e-6)
    np.testing.assert_allclose(origin[1] - y / PITCH, want[:, 1], atol=1e-6)
    back_u, back_v = lens.remove(x, y)
    np.testing.assert_allclose(back_u, u, atol=1e-9)
    np.testing.assert_allclose(back_v, v, atol=1e-9)


TAGCAMS = {"BODY2101955_RADII": "(0.283065, 0.271215, 0.24972)",
           "INS-64081_FOCAL_LENGTH": "0.00764",
           "INS-64081_PIXEL_SIZE": "2.2",
           "INS-64081_ITRANSS": "(0.0, 454.5454545454, 0.0)",
           "INS-64081_ITRANSL": "(0.0, 0.0, -454.5454545454)",
           "INS-64081_CCD_CENTER": "(1268.083, 949.747)",
           "INS-64081_DISTORTION_MODEL": "OPENCV",
           "INS-64081_OPENCV_OD_K": "(-0.53766, 0.37526, -0.18368, 0.0, 0.0, 0.0)",
           "INS-64081_OPENCV_OD_P": "(0.00023432, 0.00090875)",
           "INS-64081_OPENCV_OD_F": "(3473.26, 3473.321)",
           "INS-64081_OPENCV_OD_C": "(1269.083, 950.747)",
           "INS-64081_OPENCV_OD_A": "2.2933e-05"}
INSTRUMENT = (b"  Group = Instrument\n    InstrumentId = NAVCam\n    TargetName = Bennu\n"
              b"    CameraHeadTemperature = -28.89233 <celsius>\n  End_Group\n")


def tagcams_cube(path, naif=None, instrument=INSTRUMENT):
    """A label-only NavCam cube 1 km from a Bennu-sized body's centre, looking at it."""
    path = write_cube(path, size=2592, naif=TAGCAMS if naif is None else naif, distance_km=1.0)
    data = path.read_bytes()
    label = data[:8192].rstrip(b"\0")  # the tables stay where the label says they are
    label = label.replace(b"NaifFrameCode = -915240", b"NaifFrameCode = -64081")
    label = label.replace(b"  Group = Kernels", instrument + b"  Group = Kernels", 1)
    path.write_bytes(label.ljust(8192, b"\0") + data[8192:])
    return path


def test_tagcams_cube_reads_with_its_distortion_and_body(tmp_path):
    model = read_sensor(tagcams_cube(tmp_path / "ncm.cub"))
    assert model.distortion.model == "opencv" and model.focal_length == pytest.approx(7.64)
    # camera-head temperature scales the model focal lengths by 1 + a T
    scale = 1 + 2.2933e-05 * -28.89233
    assert model.distortion.coefficients[8] == pytest.approx(3473.26 * scale * PITCH / 7.64)
    assert (model.body_name, model.body_naif_id) == ("Bennu", 2101955)
    assert model.radii == pytest.approx((283.065, 249.72))
    line, sample = np.meshgrid(np.linspace(0.5, model.lines - 0.5, 7),
                               np.linspace(0.5, model.samples - 0.5, 7), indexing="ij")
    ray = model.image_to_ray(line, sample)
    back = model.ground_to_image(ray.origin + 1e3 * ray.direction)
    np.testing.assert_allclose(back[0], line, atol=0.01)
    np.testing.assert_allclose(back[1], sample, atol=0.01)
    # the NavCam lens bends the corner rays by hundreds of pixels: not an ideal camera
    x, y = model.detector.to_focal_plane(line, sample)
    u, v = model.distortion.remove(x, y)
    assert np.hypot(u - x, v - y).max() / PITCH > 100


def test_camera_names_a_body_proj_lacks(tmp_path):
    from demtool.camera.run import _body_of

    path = tagcams_cube(tmp_path / "ncm.cub")
    body = _body_of(read_sensor(path), path, None)
    assert body.name == "Bennu" and body.naif_id == 2101955
    assert body.radius == pytest.approx(283.065)
    crs = body.geographic_crs()
    assert crs.ellipsoid.semi_major_metre == pytest.approx(283.065)
    assert "Bennu" in crs.datum.name


def test_mapproject_body_is_the_cube_body(tmp_path):
    from demtool.mapproject.core import sensor_body

    body = sensor_body(read_sensor(tagcams_cube(tmp_path / "ncm.cub")))
    assert (body.name, body.naif_id, body.radius) == ("Bennu", 2101955, 283.065)
    assert body.geographic_crs().ellipsoid.semi_major_metre == pytest.approx(283.065)


def test_tagcams_with_another_detector_layout_is_refused(tmp_path):
    naif = dict(TAGCAMS, **{"INS-64081_ITRANSL": "(0.0, 0.0, 454.5454545454)"})
    with pytest.raises(InputError, match=r"bad\.cub: NaifKeywords 'INS-64081_ITRANSS'/"
                                         r"'_ITRANSL' are not the TAGCAMS detector layout"):
        read_cube(tagcams_cube(tmp_path / "bad.cub", naif=naif))
    naif = {k: v for k, v in TAGCAMS.items() if k != "INS-64081_OPENCV_OD_F"}
    with pytest.raises(InputError, match=r"bad2\.cub: NaifKeywords lacks the key "
                                         r"'INS-64081_OPENCV_OD_F'"):
        read_cube(tagcams_cube(tmp_path / "bad2.cub", naif=naif))


MAPPING = (b"  Group = Mapping\n    ProjectionName = Equirectangular\n    TargetName = Mars\n"
           b"    PixelResolution = 0.25256115148608 <meters/pixel>\n  End_Group\n")
LINESCAN = (b"  Group = Instrument\n    InstrumentId = CTX\n"
            b"    LineExposureDuration = 1.880 <MSEC>\n  End_Group\n")


def test_map_projected_cube_is_refused_as_a_camera(tmp_path):
    path = tagcams_cube(tmp_path / "map.cub", instrument=INSTRUMENT + MAPPING)
    with pytest.raises(InputError, match=r"map\.cub: is a map-projected cube \(ISIS Mapping "
                                         r"group: Equirectangular on Mars, 0\.2526 m/px\)"):
        read_sensor(path)


def test_line_scan_cube_is_refused_as_a_frame_camera(tmp_path):
    path = tagcams_cube(tmp_path / "ctx.cub", instrument=LINESCAN)
    # a line-scan camera demtool's ISIS line-scan reader does not model (here the NAIF
    # code of a frame camera): one line naming the camera and the way out
    with pytest.raises(InputError, match=r"ctx\.cub: is a line-scan cube of CTX \(NAIF "
                                         r"code -64081\).*ALE ISD"):
        read_sensor(path)


def test_image_cube_is_not_a_dem(tmp_path):
    path = tagcams_cube(tmp_path / "img.cub", instrument=INSTRUMENT + MAPPING)
    with pytest.raises(InputError, match=r"img\.cub: is an image cube of NAVCam \(ISIS Mapping"
                                         r".*not heights; give a DEM as the reference DEM"):
        refuse_image_as_dem(path, "reference DEM")
    dem = write_cube(tmp_path / "dem.cub")  # no Instrument / BandBin: heights
    refuse_image_as_dem(dem, "DEM")
    refuse_image_as_dem(Path(__file__), "DEM")  # not a cube: left to the raster reader


# -- with ../shared ------------------------------------------------------------------------

NAVCAM = SHARED / "isis_cubes" / "20200303T213031S138_ncm_L0-reduced.cub"
# ISIS's UnitTestOsirisRexTagCamsNAVCam (isis/tests/OsirisRexTagcamsCameraTests.cpp):
# 1-based (sample, line) → planetocentric latitude, east longitude (degrees) on the
# triaxial ellipsoid of BODY2101955_RADII (no shape model).
ISIS_NAVCAM = [(129.5, 97.0, 49.7487786981275, 43.7549667753273),
               (1.0, 1.0, 18.614472228664749, 30.4388285538537),
               (259.0, 1.0, 36.692323846663946, 81.774178147101267),
               (1.0, 194.0, 44.70914449416866, 1.6058653718226457),
               (259.0, 194.0, 71.210706457717208, 82.189907756214126)]


@pytest.mark.data
@pytest.mark.skipif(not NAVCAM.exists(), reason="../shared/data/sensors is absent")
def test_navcam_cube_matches_isis():
    model = read_sensor(NAVCAM)
    radii = np.array([283.065, 271.215, 249.72])
    for sample, line, lat, lon in ISIS_NAVCAM:
        ray = model.image_to_ray(line - 0.5, sample - 0.5)
        o, d = ray.origin / radii, ray.direction / radii
        a, b, c = d @ d, 2 * o @ d, o @ o - 1
        p = ray.origin + (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a) * ray.direction
        assert np.degrees(np.arcsin(p[2] / np.linalg.norm(p))) == pytest.approx(lat, abs=1e-6)
        assert np.degrees(np.arctan2(p[1], p[0])) % 360 == pytest.approx(lon, abs=1e-6)


@pytest.mark.data
@pytest.mark.parametrize("name, match", [
    ("isis_cubes/E0201461.tiny.cub", r"is a map-projected cube \(ISIS Mapping group: "
                                     r"Sinusoidal on Mars, 4\.676 m/px\)"),
    ("hirise_mapprojected/ESP_014038_1415_RED0.30421_33069.boulder_shift.before.cub",
     r"is a map-projected cube \(ISIS Mapping group: Equirectangular on Mars, 0\.2526 m/px"),
])
def test_shared_files_refused_in_one_true_line(name, match):
    path = SHARED / name
    if not path.exists():
        pytest.skip("../shared/data/sensors is absent")
    with pytest.raises(InputError, match=match):
        read_sensor(path)


def test_cam2map_cube_given_to_the_map_projected_route_says_what_it_lacks(tmp_path):
    from demtool.dem.inputs import read_ortho
    from demtool.sensors.isis_map import refuse_cam2map_ortho

    path = tagcams_cube(tmp_path / "map.cub", instrument=LINESCAN + MAPPING)
    with pytest.raises(InputError, match=r"map\.cub: the left orthoimage is an ISIS "
                                         r"map-projected cube of CTX \(ISIS Mapping group: "
                                         r"Equirectangular on Mars, 0\.2526 m/px\) without "
                                         r"demtool's mapproject tags: the map-projected route "
                                         r"takes two ISIS cam2map cubes .* raw line-scan "
                                         r"images"):
        refuse_cam2map_ortho(path, "the left orthoimage")
    refuse_cam2map_ortho(tagcams_cube(tmp_path / "raw.cub"), "x")  # not map-projected: fine
    # read as a cam2map ortho, its camera (a frame camera's NAIF code) is refused
    with pytest.raises(InputError, match=r"map\.cub: is a line-scan cube of CTX \(NAIF code "
                                         r"-64081\); demtool reads the ISIS line-scan models"):
        read_ortho(path, what="left orthoimage")
