"""JPL's CAHV / CAHVOR / CAHVORE models and their files (demtool.sensors.cahvor)."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors.cahvor import CahvoreCamera, cahvor_from_pinhole
from demtool.sensors.cahvor_files import parse_cahvor_text, read_cahvor
from demtool.sensors.pinhole import look_at

F, CX, CY = 1000.0, 500.0, 400.0


def _axis_camera(**kw):
    """Camera at the origin looking along +Z: H = f X + cx A, V = f Y + cy A."""
    return CahvoreCamera(C=(0, 0, 0), A=(0, 0, 1), H=(F, 0, CX), V=(0, F, CY), O=(0, 0, 1),
                         R=kw.pop("R", (0, 0, 0)), E=kw.pop("E", (0, 0, 0)), width=1000,
                         height=800, **kw)


def test_cahvor_known_values_from_gennerys_equations():
    # P = (1, 2, 10): τ = |λ|²/ζ² = 0.05, μ = R1 τ = 0.005, P' = (1.005, 2.01, 10)
    cam = _axis_camera(R=(0.0, 0.1, 0.0), model_name="cahvor")
    x, y = cam.project_xy(np.array([1.0, 2.0, 10.0]))
    assert (float(x), float(y)) == pytest.approx((600.5, 601.0), abs=1e-9)
    # with R0 and R2: μ = 0.02 + 0.1·0.05 + 0.3·0.05² = 0.02575
    cam = _axis_camera(R=(0.02, 0.1, 0.3), model_name="cahvor")
    x, y = cam.project_xy(np.array([1.0, 2.0, 10.0]))
    assert (float(x), float(y)) == pytest.approx((500 + 100 * 1.02575, 400 + 200 * 1.02575))


def test_cahvore_fisheye_known_values():
    # L = 0, E = 0, R = 0: χ = θ, an equidistant fish-eye, r = f θ
    cam = _axis_camera(linearity=0.0, model_name="cahvore")
    x, y = cam.project_xy(np.array([1.0, 0.0, 1.0]))
    assert (float(x), float(y)) == pytest.approx((CX + F * np.pi / 4, CY), abs=1e-9)
    # 100° off the axis: still imaged by a fish-eye (behind the image plane)
    x, _ = cam.project_xy(np.array([np.sin(np.radians(100)), 0, np.cos(np.radians(100))]))
    assert float(x) == pytest.approx(CX + F * np.radians(100))
    # with a moving pupil s(θ) = (θ/sin θ − 1) E0: the ray through C + s O reaches P at θ
    e0 = 0.05
    cam = _axis_camera(linearity=0.0, E=(e0, 0, 0), model_name="cahvore")
    p = np.array([0.3, 0.0, 0.4])
    lo, hi = 0.1, 1.5  # solve tan θ = λ / (ζ − s(θ)) by bisection, independently
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        s = (mid / np.sin(mid) - 1) * e0
        lo, hi = (mid, hi) if np.arctan2(0.3, 0.4 - s) > mid else (lo, mid)
    x, _ = cam.project_xy(p)
    assert float(x) == pytest.approx(CX + F * 0.5 * (lo + hi), abs=1e-6)
    ray = cam.ray_xy(x, CY)
    to_point = p - ray.origin
    np.testing.assert_allclose(ray.direction, to_point / np.linalg.norm(to_point), atol=1e-9)


@pytest.mark.parametrize("kw", [
    dict(),  # CAHV
    dict(radial=(0.01, -0.2, 0.05)),  # CAHVOR
    dict(radial=(0.0, -0.05, 0.01), entrance=(0.01, 0.005, 0.001), linearity=0.0),
    dict(radial=(0.0, 0.02, 0.0), entrance=(0.02, 0.0, 0.0), linearity=-0.5),
    dict(radial=(0.0, 0.02, 0.0), entrance=(0.02, 0.0, 0.0), linearity=0.5),
])
def test_round_trips_within_a_hundredth_of_a_pixel(kw):
    pin = look_at((0, 0, 1), (0, 3, 0), up=(0, 0, 1), focal_px=300, width=640, height=480)
    cam = cahvor_from_pinhole(pin.K, pin.R, pin.center, width=640, height=480, **kw)
    rng = np.random.default_rng(0)
    line, sample = rng.uniform(0.5, 479.5, 2000), rng.uniform(0.5, 639.5, 2000)
    ray = cam.image_to_ray(line, sample)
    points = ray.origin + rng.uniform(0.3, 20, 2000)[:, None] * ray.direction
    line2, sample2 = cam.ground_to_image(points)
    assert np.max(np.hypot(line2 - line, sample2 - sample)) < 0.01
    if not kw:  # CAHV is the pinhole
        np.testing.assert_allclose(cam.project(points), pin.project(points), atol=1e-9)


VW_CAHVORE = """C = 0.5 -0.3 -1.9
A = 0.9 0.1 0.42
H = 300 -500 200
V = 100 50 -600
O = 0.91 0.09 0.40
R = 0.001 -0.02 0.003
E = 0.002 0.01 -0.001
T = 2
P = 0
"""

JPL_CAHVOR = """# CAHVOR camera model, JPL format
Model = CAHVOR = perspective, distortion
Dimensions = 1024 1024
C =  0.5 -0.3 -1.9
A =  0.9  0.1  0.42
H =  300 -500  200
V =  100   50 -600
O =  0.91 0.09 0.40
R =  0.0 -0.02 0.003
S =
   1 0 0
   0 1 0
Hs = 600.1
Theta = -1.57
"""


def test_asp_and_jpl_files_are_read(tmp_path):
    (tmp_path / "a.cahvore").write_text(VW_CAHVORE)
    (tmp_path / "b.cahvor").write_text(JPL_CAHVOR)
    from demtool.sensors import read_sensor

    ore = read_sensor(tmp_path / "a.cahvore")
    assert ore.model_name == "cahvore" and ore.linearity == 0.0 and ore.radii is None
    np.testing.assert_allclose(ore.E, [0.002, 0.01, -0.001])
    assert np.linalg.norm(ore.A) == pytest.approx(1.0)
    cahvor = read_cahvor(tmp_path / "b.cahvor")
    assert cahvor.model_name == "cahvor" and (cahvor.width, cahvor.height) == (1024, 1024)
    from demtool.sensors.cahvor_files import cahvor_text

    (tmp_path / "c.cahvore").write_text(cahvor_text(ore))
    again = read_cahvor(tmp_path / "c.cahvore")
    for key in ("C", "A", "H", "V", "O", "R", "E"):
        np.testing.assert_allclose(getattr(again, key), getattr(ore, key), rtol=1e-14)
    body = read_cahvor(tmp_path / "b.cahvor", radii=(3396190.0, 3376200.0))
    assert body.radii == (3396190.0, 3376200.0)


PDS3 = """PDS_VERSION_ID = PDS3
OBJECT = IMAGE
  LINES = 1024
  LINE_SAMPLES = 1024
END_OBJECT = IMAGE
GROUP = GEOMETRIC_CAMERA_MODEL_PARMS
 ^MODEL_DESC = "GEOMETRIC_CM.TXT"
 MODEL_TYPE = CAHVORE
 MODEL_COMPONENT_ID = ("C","A","H","V","O","R","E","T","P")
 MODEL_COMPONENT_1 = ( 0.5, -0.3,
   -1.9 )
 MODEL_COMPONENT_2 = ( 0.9, 0.1, 0.42 )
 MODEL_COMPONENT_3 = ( 300.0, -500.0, 200.0 )
 MODEL_COMPONENT_4 = ( 100.0, 50.0, -600.0 )
 MODEL_COMPONENT_5 = ( 0.91, 0.09, 0.40 )
 MODEL_COMPONENT_6 = ( 0.001, -0.02, 0.003 )
 MODEL_COMPONENT_7 = ( 0.002 <m>, 0.01 <m>, -0.001 <m> )
 MODEL_COMPONENT_8 = 3.0
 MODEL_COMPONENT_9 = 0.25
 REFERENCE_COORD_SYSTEM_NAME = ROVER_NAV_FRAME
END_GROUP = GEOMETRIC_CAMERA_MODEL_PARMS
END
"""


def test_pds3_geometric_camera_model_group(tmp_path):
    from demtool.sensors import read_sensor

    (tmp_path / "nav.lbl").write_text(PDS3)
    cam = read_sensor(tmp_path / "nav.lbl")
    assert cam.model_name == "cahvore" and cam.linearity == 0.25
    assert (cam.width, cam.height) == (1024, 1024)
    np.testing.assert_allclose(cam.C, [0.5, -0.3, -1.9])
    (tmp_path / "other.lbl").write_text(PDS3.replace("ROVER_NAV_FRAME", "MARS_BODY_FIXED"))
    with pytest.raises(InputError, match="MARS_BODY_FIXED.*give the body"):
        read_sensor(tmp_path / "other.lbl")


@pytest.mark.parametrize("edit, message", [
    (("A = 0.9 0.1 0.42\n", ""), "lacks the component 'A'"),
    (("T = 2", "T = 4"), "type T = 4"),
    (("T = 2\nP = 0", "T = 3\nP = 1.5"), "linearity P = 1.5"),
    (("H = 300 -500 200", "H = 0.9 0.1 0.42"), "'H' is parallel to A"),
    (("O = 0.91 0.09 0.40", "O = -0.91 -0.09 -0.40"), "more than 90°"),
    (("R = 0.001 -0.02 0.003", "R = 0.001 nan 0.003"), "'R' is not finite"),
    (("C = 0.5 -0.3 -1.9", "C = 0.5 -0.3"), "'C' needs 3 numbers"),
])
def test_bad_files_are_refused_in_one_line(tmp_path, edit, message):
    path = tmp_path / "bad.cahvore"
    path.write_text(VW_CAHVORE.replace(*edit))
    with pytest.raises(InputError, match=message) as info:
        read_cahvor(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    assert parse_cahvor_text("C = 1 2 3") == {"C": pytest.approx(np.array([1.0, 2, 3]))}
