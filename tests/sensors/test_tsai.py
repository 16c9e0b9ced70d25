"""ASP .tsai pinholes: values against closed forms and OpenCV, round trips, bad input."""

import cv2
import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import TsaiCamera, read_sensor, read_tsai
from tests.helpers.tsai import HEADER

MOON = (1737400.0, 1737400.0)


def write(tmp_path, lens="NULL\n", name="cam.tsai", header=HEADER):
    path = tmp_path / name
    path.write_text(header + lens)
    return path


def test_null_lens_values(tmp_path):
    model = read_sensor(write(tmp_path), radii=MOON)
    assert isinstance(model, TsaiCamera) and model.focal_px == pytest.approx(2000.0)
    # The principal point (u, v) = (512, 512), CSM (512.5, 512.5), sees the sub-camera point.
    np.testing.assert_allclose(model.image_to_ground(512.5, 512.5), (MOON[0], 0, 0), atol=1e-6)
    # 100 px right: direction (−1, 0.05, 0); the sphere hit in closed form.
    d = np.array([-1.0, 0.05, 0.0]) / np.hypot(1.0, 0.05)
    c = np.array([1837400.0, 0, 0])
    s = -(c @ d) - np.sqrt((c @ d) ** 2 - (c @ c - MOON[0] ** 2))
    np.testing.assert_allclose(model.image_to_ground(512.5, 612.5), c + s * d, atol=1e-6)
    line, sample = model.ground_to_image(c + s * d)
    assert (line, sample) == (pytest.approx(512.5, abs=1e-9), pytest.approx(612.5, abs=1e-9))


def test_tsai_lens_matches_opencv(tmp_path):
    lens = "TSAI\nk1 = -0.09\nk2 = 0.11\np1 = -0.0003\np2 = 0.0004\nk3 = -0.03\n"
    model = read_tsai(write(tmp_path, lens), radii=MOON)
    rng = np.random.default_rng(0)
    lines, samples = rng.uniform(0.5, 1023.5, (2, 50))
    ground = model.image_to_ground(lines, samples)
    rvec, _ = cv2.Rodrigues(model.R)
    uv, _ = cv2.projectPoints(ground, rvec, model.t, model.K,
                              np.array([-0.09, 0.11, -0.0003, 0.0004, -0.03]))
    np.testing.assert_allclose(uv[:, 0, 0] + 0.5, samples, atol=1e-6)
    np.testing.assert_allclose(uv[:, 0, 1] + 0.5, lines, atol=1e-6)


def vw_brown_conrady(px, py, cu, cv, xp, yp, k1, k2, k3, p1, p2, phi):
    """VisionWorkbench BrownConradyDistortion::undistorted_coordinates, physical units."""
    ix, iy = px - xp - cu, py - yp - cv
    r2 = ix * ix + iy * iy
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    tangential = p1 * r2 + p2 * r2 ** 2
    return ix * radial - tangential * np.sin(phi) + cu, iy * radial + tangential * np.cos(phi) + cv


def vw_photometrix(px, py, cu, cv, xp, yp, k1, k2, k3, p1, p2):
    """VisionWorkbench PhotometrixLensDistortion::undistorted_coordinates."""
    x, y = px - xp - cu, py - yp - cv
    r2 = x * x + y * y
    drr = k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return (px + x * drr + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y,
            py + y * drr + p2 * (r2 + 2 * y * y) + 2 * p1 * x * y)


@pytest.mark.parametrize("lens, params", [
    ("BrownConrady", dict(xp=0.02, yp=-0.01, k1=1.3e-4, k2=-2.0e-7, k3=1.0e-9, p1=2e-5,
                          p2=-1e-7, phi=0.3)),
    ("Photometrix", dict(xp=0.004, yp=-0.019, k1=1.3e-4, k2=-2.0e-7, k3=-5.3e-11, p1=7.2e-6,
                         p2=2.3e-6)),
])
def test_asp_lenses_follow_visionworkbench(tmp_path, lens, params):
    text = lens + "\n" + "".join(f"{k} = {v}\n" for k, v in params.items())
    if lens == "Photometrix":
        text += "b1 = 0\nb2 = 0\n"
    model = read_tsai(write(tmp_path, text), radii=MOON)
    rng = np.random.default_rng(1)
    lines, samples = rng.uniform(0.5, 1023.5, (2, 40))
    # Distorted physical coordinates of the pixels (pitch 0.01, pixel centres at integers).
    px, py = (samples - 0.5) * 0.01, (lines - 0.5) * 0.01
    formula = vw_brown_conrady if lens == "BrownConrady" else vw_photometrix
    ux, uy = formula(px, py, 5.12, 5.12, **params)
    # The ray through an undistorted physical point: camera direction ((ux−cu)/fu, (uy−cv)/fv, 1).
    cam = np.column_stack([(ux - 5.12) / 20, (uy - 5.12) / 20, np.ones_like(ux)])
    expected = cam @ model.R
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(model.image_to_ray(lines, samples).direction, expected,
                               atol=1e-12)
    # ground → image inverts it (Newton on the VisionWorkbench formula).
    line, sample = model.ground_to_image(model.image_to_ground(lines, samples))
    np.testing.assert_allclose(line, lines, atol=1e-6)
    np.testing.assert_allclose(sample, samples, atol=1e-6)


def test_axes_directions_permute_the_camera(tmp_path):
    # Swapping u and v with a flipped w is the same camera as R' = R · M for M = [u; v; w]ᵀ.
    header = HEADER.replace("u_direction = 1 0 0", "u_direction = 0 1 0") \
        .replace("v_direction = 0 1 0", "v_direction = 1 0 0") \
        .replace("w_direction = 0 0 1", "w_direction = 0 0 -1")
    swapped = read_tsai(write(tmp_path, header=header), radii=MOON)
    plain = read_tsai(write(tmp_path, name="plain.tsai"), radii=MOON)
    np.testing.assert_allclose(swapped.R, np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]]) @ plain.R)


def test_no_radii_says_so(tmp_path):
    model = read_tsai(write(tmp_path))
    with pytest.raises(ValueError, match="radii"):
        model.image_to_ground(1.0, 1.0)


@pytest.mark.parametrize("text, match", [
    (HEADER.replace("fv = 20", "fv = twenty"), r"bad\.tsai: line 4: 'fv' has a non-numeric"),
    (HEADER.replace("C = 1837400 0 0", "C = 1837400 0"), r"bad\.tsai: line 10: 'C' needs 3"),
    (HEADER.replace("pitch = 0.01", "pitch: 0.01"), r"bad\.tsai: line 12: cannot parse"),
    (HEADER.replace("cu = 5.12\n", ""), r"bad\.tsai: lacks the key 'cu'"),
    (HEADER + "FISHEYE\nk1 = 0.1\n", r"bad\.tsai: line 13: lens model 'FISHEYE'"),
    (HEADER + "TSAI\nk1 = 0.1\nk2 = 0\np1 = 0\n", r"bad\.tsai: the tsai lens lacks .*'p2'"),
    (HEADER + "TSAI\nk1 = 0.1\nk9 = 0\n", r"bad\.tsai: line 15: unknown tsai lens parameter"),
    (HEADER.replace("fv = 20", "fv = 21") + "BrownConrady\n" + "".join(
        f"{k} = 0\n" for k in ("xp", "yp", "k1", "k2", "k3", "p1", "p2", "phi")),
     r"bad\.tsai: a brownconrady lens with fu != fv"),
])
def test_malformed_tsai_is_one_line_naming_file_and_line(tmp_path, text, match):
    path = tmp_path / "bad.tsai"
    path.write_text(text)
    with pytest.raises(InputError, match=match) as info:
        read_sensor(path)
    assert "\n" not in str(info.value)


def test_non_brown_lens_is_not_silently_dropped_from_a_cameras_file(tmp_path):
    from demtool.sensors.pinhole import cameras_to_arrays

    lens = "BrownConrady\n" + "".join(f"{k} = {v}\n" for k, v in
                                      dict(xp=0, yp=0, k1=1e-4, k2=0, k3=0, p1=0, p2=0,
                                           phi=0).items())
    model = read_tsai(write(tmp_path, lens))
    with pytest.raises(ValueError, match="brownconrady lens cannot be stored"):
        cameras_to_arrays(["cam"], [model])
    plain = read_tsai(write(tmp_path, "TSAI\nk1 = 0.1\nk2 = 0\np1 = 0\np2 = 0\n", "t.tsai"))
    np.testing.assert_allclose(cameras_to_arrays(["t"], [plain])["distortion"][0],
                               [0.1, 0, 0, 0, 0])
